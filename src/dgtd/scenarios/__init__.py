"""Named scenarios: each is a function returning a frozen `Scenario` (problem, network, algorithm, sampling).

Scenarios are data: the CLI and experiment files refer to them by name, and flags override their fields.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache

import numpy as np

from dgtd.algorithms.dgtd import DGTD
from dgtd.errors import DgtdInputError
from dgtd.graphs import topologies
from dgtd.graphs.random import random_edges
from dgtd.problems import tasks
from dgtd.problems.features import gaussian_rbf
from dgtd.problems.model import Problem, make_problem
from dgtd.scenarios.base import Scenario
from dgtd.scenarios.tuned import tuned_steps
from dgtd.sources.model import Sampling

PAPER_EXAMPLE_1_P = np.array([[0.1, 0.5, 0.2, 0.2], [0.5, 0.0, 0.1, 0.4], [0.0, 0.9, 0.1, 0.0], [0.2, 0.1, 0.1, 0.6]])


def paper_example_1(edge_prob: float = 0.8) -> Scenario:
    """The paper's Example 1: a four-state chain, gamma = 0.8, five agents, reward 50 at state 4 for agent 1 only.

    Features phi(s) = [exp(-s^2), exp(-(s-4)^2)] with states numbered 1..4; the paper's own step sizes
    alpha_k = 10 / sqrt(k + 100) and kappa = 1 (not DGTD's faster defaults, 10 / sqrt(k + 1000) and kappa = 3).
    The paper's network figure is missing: we use a ring of five agents whose every link fails
    independently at each step with probability 0.2 (up with probability ``edge_prob``), so that the graph
    at a given step is often disconnected while the mean graph (a ring) is connected, as
    Assumption 2 (mean connectivity) requires. Each agent draws its own i.i.d. sample s ~ d, as Algorithm 1 states.
    """
    R = np.zeros((5, 4))
    R[0, 3] = 50.0
    problem = make_problem(
        PAPER_EXAMPLE_1_P,
        R,
        gaussian_rbf([1, 2, 3, 4], [0, 4]),
        0.8,
        name="paper-example-1",
        state_labels=(1, 2, 3, 4),
    )
    return Scenario(
        problem=problem,
        network=random_edges(topologies.ring(5), edge_prob),
        algorithm=DGTD(alpha0=10.0, beta=100.0, schedule="sqrt", kappa=1.0),
        sampling=Sampling(mode="iid", shared=False),
        iterations=1_000_000,
        description="the paper's Example 1: 4-state chain, 5 agents on a ring with random link failures",
        compare_settings=tuned_steps("paper-example-1"),
    )


@lru_cache(maxsize=2)
def paper_example_2(edge_prob: float | None = None) -> Scenario:
    """The paper's Example 2: three robots patrol a 20 m x 20 m area on a 20 x 20 grid, talking within 5 m.

    World, regions and the estimated reference chain: `dgtd.scenarios.robots`. Tabular features, gamma = 0.5,
    50 000 iterations as in the paper; samples and links come from the simulated robots (`PatrolSource`).
    The paper gives no step sizes for this example; we keep its schedule alpha_k = alpha0 / sqrt(k + beta) with
    alpha0 = 10, beta = 1000 and kappa = 3. When all three robots are linked, L(k) has eigenvalue 3, and the
    consensus part of one step (v, mu, w along that eigenvector) is a contraction only for alpha_k below about
    0.41 with kappa = 3 (0.18 with kappa = 1): alpha_0 = 10 / sqrt(1000) = 0.32 keeps every step stable, and
    alpha0 = 10 keeps the per-visit learning rate of a state visited once in 4000 steps from stalling.
    The reference chain is cached for the process (the simulation takes a few seconds).
    """
    if edge_prob is not None:
        raise DgtdInputError(
            "the links of paper-example-2 come from the robots' positions (5 m radius); --edge-prob does not apply"
        )
    from dgtd.scenarios.robots import PatrolWorld, patrol_scenario

    return patrol_scenario(
        PatrolWorld(),
        5.0,
        algorithm=DGTD(alpha0=10.0, beta=1000.0, schedule="sqrt", kappa=3.0),
        iterations=50_000,
        name="paper-example-2",
        description="the paper's Example 2: 3 robots patrol a 20x20 grid, linked within 5 m, one danger map",
    )


def _task(
    problem: Problem,
    edge_prob: float,
    dgtd: DGTD,
    iterations: int,
    description: str,
    steps: dict,
    sampling: Sampling = Sampling(mode="iid", shared=False),
) -> Scenario:
    """A benchmark task (`dgtd.problems.tasks`) on a ring whose links are each up with ``edge_prob``."""
    return Scenario(
        problem,
        random_edges(topologies.ring(problem.n_agents), edge_prob),
        dgtd,
        sampling,
        iterations,
        description,
        compare_settings=steps,
    )


def baird_scenario(edge_prob: float = 0.8) -> Scenario:
    """Baird's counterexample, off-policy, 5 agents; off-policy TD(0) diverges here. Constant steps (0.02), as in
    Sutton and Barto's experiments on it (section 11.7), and 4 million iterations: the gradient methods' values
    settle along a direction of eigenvalue ~2e-5, which a decaying step would not resolve in any budget."""
    return _task(
        tasks.baird(n_agents=5),
        edge_prob,
        DGTD(alpha0=0.02, schedule="constant"),
        4_000_000,
        "Baird's counterexample (7 states, 8 features, off-policy), 5 agents on a ring with link failures",
        tuned_steps("baird"),
    )


def boyan_scenario(edge_prob: float = 0.8) -> Scenario:
    """The episodic Boyan chain of Dann et al. (2014), 10 agents; DGTD's default step sizes."""
    return _task(
        tasks.boyan(n_agents=10),
        edge_prob,
        DGTD(),
        200_000,
        "Boyan chain (14 states, 4 features, episodic), 10 agents on a ring with link failures",
        tuned_steps("boyan"),
    )


def random_mdp_scenario(edge_prob: float = 0.8, seed: int = 0) -> Scenario:
    """Dann et al.'s 400-state random MDP, on-policy, 10 agents; alpha0 = 0.3, as its 200 features have |phi|^2 ~ 70
    (DGTD's default alpha0 = 10 suits features of unit scale)."""
    return _task(
        tasks.random_mdp(n_agents=10, seed=seed),
        edge_prob,
        DGTD(alpha0=0.3, beta=100.0),
        100_000,
        "random MDP (400 states, 10 actions, 200 features), on-policy, 10 agents on a ring",
        tuned_steps("random-mdp"),
    )


def random_mdp_off_scenario(edge_prob: float = 0.8, seed: int = 0) -> Scenario:
    """Dann et al.'s 400-state random MDP, off-policy (random behaviour policy), 10 agents; alpha0 = 0.3 as
    on-policy."""
    return _task(
        tasks.random_mdp(n_agents=10, off_policy=True, seed=seed),
        edge_prob,
        DGTD(alpha0=0.3, beta=100.0),
        100_000,
        "random MDP (400 states, 10 actions, 200 features), off-policy, 10 agents on a ring",
        tuned_steps("random-mdp-off"),
    )


def random_walk_scenario(edge_prob: float = 0.8) -> Scenario:
    """An on-policy random walk on 20 states with tabular features, 10 agents; DGTD's default step sizes."""
    return _task(
        tasks.random_walk(n_agents=10),
        edge_prob,
        DGTD(),
        100_000,
        "random walk (20 states, tabular features, on-policy), 10 agents on a ring with link failures",
        tuned_steps("random-walk"),
    )


def garnet_scenario(
    edge_prob: float = 0.8,
    n_states: int = 30,
    branching: int = 3,
    n_agents: int = 10,
    n_features: int = 8,
    seed: int = 0,
) -> Scenario:
    """A random ergodic Garnet chain (default 30 states, 3 successors, 10 agents, 8 features); DGTD's default step
    sizes."""
    return _task(
        tasks.garnet(n_states, branching, n_agents, n_features, seed=seed),
        edge_prob,
        DGTD(),
        100_000,
        f"Garnet chain ({n_states} states, {branching} successors, {n_features} features), {n_agents} agents",
        tuned_steps("garnet"),
    )


def mpe_spread_scenario(
    agents: int = 3, radius: float = 1.0, iterations: int = 60_000, policy: str = "heuristic"
) -> Scenario:
    """MPE2 simple_spread: N particles (3) cover N landmarks, linked within a radius; estimated reference (LSTD)."""
    from dgtd.scenarios.mpe import mpe_spread

    return mpe_spread(agents=agents, radius=radius, iterations=iterations, policy=policy)


SCENARIOS: dict[str, Callable[..., Scenario]] = {
    "paper-example-1": paper_example_1,
    "paper-example-2": paper_example_2,
    "baird": baird_scenario,
    "boyan": boyan_scenario,
    "random-mdp": random_mdp_scenario,
    "random-mdp-off": random_mdp_off_scenario,
    "garnet": garnet_scenario,
    "random-walk": random_walk_scenario,
    "mpe-spread": mpe_spread_scenario,
}


def get_scenario(name: str, **params) -> Scenario:
    """The named scenario, or a `DgtdInputError` that lists the known names and the closest one."""
    if name not in SCENARIOS:
        import difflib

        close = difflib.get_close_matches(name, SCENARIOS, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise DgtdInputError(f"unknown scenario {name!r} (known: {', '.join(SCENARIOS)}){hint}")
    return SCENARIOS[name](**params)
