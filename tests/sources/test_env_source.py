"""Model-free distributed evaluation on a PettingZoo ParallelEnv whose model is known, so that the estimated reference
(LSTD on an independent batch) and the runs can be checked against the exact solution."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pettingzoo", reason="the environment extra (pip install dgtd[envs]) is not installed")

from gymnasium import spaces  # noqa: E402
from pettingzoo import ParallelEnv  # noqa: E402

from dgtd.algorithms import make_algorithm  # noqa: E402
from dgtd.errors import DgtdInputError  # noqa: E402
from dgtd.graphs import topologies  # noqa: E402
from dgtd.graphs.random import random_edges  # noqa: E402
from dgtd.problems import exact  # noqa: E402
from dgtd.problems.model import make_problem  # noqa: E402
from dgtd.run.loop import RunSettings, run  # noqa: E402
from dgtd.sources.env import EnvSource, reference_from_env  # noqa: E402
from dgtd.sources.model import Sampling  # noqa: E402

P = np.array([[0.1, 0.6, 0.3, 0.0], [0.0, 0.2, 0.5, 0.3], [0.4, 0.0, 0.2, 0.4], [0.5, 0.2, 0.0, 0.3]])
R = np.array([[1.0, 0.0, 0.0, 2.0], [0.0, 3.0, 0.0, 0.0], [0.5, 0.5, 1.0, 0.0]])  # agent i's reward at state s
GAMMA = 0.8


class Chain(ParallelEnv):
    """Four states moving by P whatever the agents do (one action each); agent i earns R[i, s] at state s, and its
    observation and the env's state are the one-hot state."""

    metadata = {"name": "chain_v0"}

    def __init__(self):
        self.possible_agents = [f"agent_{i}" for i in range(3)]
        self.agents = []
        self.rng = np.random.default_rng()
        self.s = 0

    def observation_space(self, agent):
        return spaces.Box(0.0, 1.0, (4,))

    def action_space(self, agent):
        return spaces.Discrete(1)

    def state(self):
        return np.eye(4)[self.s]

    def reset(self, seed=None, options=None):
        self.rng = np.random.default_rng(seed)
        self.agents = list(self.possible_agents)
        self.s = int(self.rng.integers(4))
        return {a: self.state() for a in self.agents}, {a: {} for a in self.agents}

    def step(self, actions):
        rewards = {a: R[i, self.s] for i, a in enumerate(self.agents)}
        self.s = int(self.rng.choice(4, p=P[self.s]))
        obs = {a: self.state() for a in self.agents}
        return (
            obs,
            rewards,
            {a: False for a in self.agents},
            {a: False for a in self.agents},
            {a: {} for a in self.agents},
        )


def exact_w_star() -> np.ndarray:
    return exact.w_star(exact.Moments(make_problem(P, R, np.eye(4), GAMMA)))


def source(seed, seed_ids, offset=0):
    return EnvSource(
        Chain, lambda states: states, seed, seed_ids, network=random_edges(topologies.path(3), 0.8), seed_offset=offset
    )


@pytest.fixture(scope="module")
def reference():
    reference, links = reference_from_env(
        lambda g: source(123, [g], offset=10_000), 4, GAMMA, "chain", steps=20_000, groups=8
    )
    assert np.allclose(links, 0.8, atol=0.01)  # each link up with probability 0.8: 160,000 draws each
    return reference


def test_the_estimated_reference_matches_the_exact_w_star_within_its_standard_error(reference):
    """8 independent env copies x 20,000 steps. |w_hat - w*| <= 4 standard errors in every component (a normal
    estimate misses that with probability 6e-5 per component), and the error is small in itself (< 2 %)."""
    w, se = reference.w_star, reference.w_star_stderr
    assert np.all(np.abs(w - exact_w_star()) <= 4 * se + 1e-9), (w, exact_w_star(), se)
    assert np.abs(w - exact_w_star()).max() < 0.02 * np.abs(exact_w_star()).max()
    assert reference.summary()["estimated"] and reference.transitions == 160_000


def test_dgtd_on_the_environment_reaches_the_reference(reference):
    """DGTD's defaults on 3 agents that each see only their own reward: the tail average of every agent within 5 % of
    the estimated reference in the d-weighted value error (measured: 0.26 % and 0.07 % on 2 seeds of 60,000 steps;
    0.16 % and 0.17 % from the exact w*)."""
    result = run(
        reference,
        random_edges(topologies.path(3), 0.8),
        make_algorithm("dgtd"),
        Sampling(),
        RunSettings(iterations=60_000, seeds=2, checkpoints=10),
        source=source(0, range(2)),
    )
    assert np.allclose(result.w_star, reference.w_star)
    assert result.metrics["value_error_tail"][-1].max() < 0.05
    assert result.info["d"] is None  # no model: no stationary distribution


def test_a_seeds_samples_do_not_depend_on_the_other_seeds():
    one, two = source(5, [1]), source(5, [0, 1])
    one.start(), two.start()
    a, b = one.next_block(50), two.next_block(50)
    assert np.array_equal(a.r[:, 0], b.r[:, 1]) and np.array_equal(a.up[:, 0], b.up[:, 1])


def test_an_object_that_is_not_a_parallel_env_is_refused_in_one_line():
    with pytest.raises(DgtdInputError, match="has no reset"):
        EnvSource(lambda: object(), lambda s: s, 0, [0], network=random_edges(topologies.path(3), 1.0)).start()


@pytest.mark.parametrize("action", [17, -1, 0.5])
def test_a_policy_choosing_an_action_outside_its_space_is_refused_in_one_line(action):
    """Action 17 (or -1, or 0.5) for the chain's Discrete(2) space: refused naming the policy, the agent, the action
    and the space, rather than handed to the env (which may take it)."""
    policy = lambda agent, observation, space, rng: action  # noqa: E731
    src = EnvSource(Chain, lambda s: s, 0, [0], network=random_edges(topologies.path(3), 1.0), policy=policy)
    src.start()
    with pytest.raises(DgtdInputError, match=f"returned {action} for agent_0, outside its action space Discrete"):
        src.next_block(3)


def test_features_of_the_wrong_shape_or_nan_are_refused():
    bad = EnvSource(Chain, lambda s: s[:, :2][:-1], 0, [0], network=random_edges(topologies.path(3), 1.0))
    bad.start()
    with pytest.raises(DgtdInputError, match="features of 20 states came out with shape"):
        bad.next_block(10)
    nan = EnvSource(Chain, lambda s: s * np.nan, 0, [0], network=random_edges(topologies.path(3), 1.0))
    nan.start()
    with pytest.raises(DgtdInputError, match="NaN"):
        nan.next_block(10)


@pytest.mark.slow
def test_mpe_spread_runs_from_the_command_line_and_says_its_reference_is_estimated(run_cli, tmp_path):
    """A short `dgtd run mpe-spread` (MPE2's simple_spread, 3 particles linked within a radius): it writes the
    numbers and says in summary.json that the reference is estimated, and how precisely."""
    import json

    pytest.importorskip("mpe2", reason="MPE2 is part of the environment extra")
    out = tmp_path / "mpe"
    code, text, err = run_cli("run", "mpe-spread", "-T", "600", "--no-plots", "--no-progress", "--out", out)
    assert code == 0, err
    assert "w* is estimated (no model)" in text
    summary = json.loads((out / "summary.json").read_text())
    ref = summary["reference"]
    assert ref["estimated"] and ref["transitions"] == 32_000 and 0 < ref["value_stderr_relative"] < 0.05
    assert len(summary["w_star"]) == 7 and summary["stationary_distribution"] is None


@pytest.mark.parametrize("returned", ["ab", None, np.ones((20, 1)) * 1j])
def test_features_that_are_not_real_numbers_are_one_line(returned):
    """Text, None or complex numbers from the user's features: one line naming them, not a NumPy traceback (text)
    or a silently dropped imaginary part (complex)."""
    src = EnvSource(Chain, lambda s: returned, 0, [0], network=random_edges(topologies.path(3), 1.0))
    src.start()
    with pytest.raises(DgtdInputError, match="the features .*<lambda> returned .*, not real numbers"):
        src.next_block(10)


@pytest.mark.parametrize(
    "where, words",
    [
        (lambda env: "here", "returned 'here', not real numbers"),
        (lambda env: np.zeros((2, 2)), "positions of 3 agents, one row each: got shape \\(2, 2\\)"),
        (lambda env: np.full((3, 2), np.nan), "NaN or infinite"),
    ],
)
def test_positions_that_are_not_one_finite_row_per_agent_are_one_line(where, words):
    """A user's positions(env) feeds the proximity links: text, a row missing or NaN (no link would ever be up,
    silently) are refused in one line."""
    from dgtd.graphs.proximity import ProximityNetwork

    proximity = ProximityNetwork(3, 1.0)
    src = EnvSource(Chain, lambda s: s, 0, [0], positions=where, proximity=proximity)
    src.start()
    with pytest.raises(DgtdInputError, match=words):
        src.next_block(3)
