"""Named scenarios: each is a function returning a frozen `Scenario` (problem, network, algorithm, sampling).

Scenarios are data: the CLI and experiment files refer to them by name, and flags override their fields.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from dgtd.algorithms.dgtd import DGTD
from dgtd.errors import DgtdInputError
from dgtd.graphs import topologies
from dgtd.graphs.random import RandomEdges, random_edges
from dgtd.problems.features import gaussian_rbf
from dgtd.problems.model import Problem, make_problem
from dgtd.run.sampling import Sampling


@dataclass(frozen=True, eq=False)
class Scenario:
    """A ready-to-run setting; ``iterations`` is the run length the scenario is meant to be judged at."""

    problem: Problem
    network: RandomEdges
    algorithm: DGTD
    sampling: Sampling
    iterations: int
    description: str


PAPER_EXAMPLE_1_P = np.array(
    [[0.1, 0.5, 0.2, 0.2],
     [0.5, 0.0, 0.1, 0.4],
     [0.0, 0.9, 0.1, 0.0],
     [0.2, 0.1, 0.1, 0.6]]
)


def paper_example_1(edge_prob: float = 0.8) -> Scenario:
    """The paper's Example 1: a four-state chain, gamma = 0.8, five agents, reward 50 at state 4 for agent 1 only.

    Features phi(s) = [exp(-s^2), exp(-(s-4)^2)] with states numbered 1..4; alpha_k = 10 / sqrt(k + 100);
    kappa = 1. The paper's network figure is missing: we use a ring of five agents whose every link fails
    independently at each step with probability 0.2 (up with probability ``edge_prob``), so that the graph
    at a given step is often disconnected while the mean graph (a ring) is connected, as
    `assumption:connected` requires. Each agent draws its own i.i.d. sample s ~ d, as Algorithm 1 states.
    """
    R = np.zeros((5, 4))
    R[0, 3] = 50.0
    problem = make_problem(
        PAPER_EXAMPLE_1_P, R, gaussian_rbf([1, 2, 3, 4], [0, 4]), 0.8, name="paper-example-1",
        state_labels=(1, 2, 3, 4),
    )
    return Scenario(
        problem=problem,
        network=random_edges(topologies.ring(5), edge_prob),
        algorithm=DGTD(alpha0=10.0, beta=100.0, schedule="sqrt", kappa=1.0),
        sampling=Sampling(mode="iid", shared=False),
        iterations=1_000_000,
        description="the paper's Example 1: 4-state chain, 5 agents on a ring with random link failures",
    )


SCENARIOS: dict[str, Callable[..., Scenario]] = {
    "paper-example-1": paper_example_1,
}


def get_scenario(name: str, **params) -> Scenario:
    """The named scenario, or a `DgtdInputError` that lists the known names and the closest one."""
    if name not in SCENARIOS:
        import difflib

        close = difflib.get_close_matches(name, SCENARIOS, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise DgtdInputError(f"unknown scenario {name!r} (known: {', '.join(SCENARIOS)}){hint}")
    return SCENARIOS[name](**params)
