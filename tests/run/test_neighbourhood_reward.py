"""Networked learners' neighbourhood estimate of the team's reward (`--team-reward neighbourhood`,
`dgtd.algorithms.team_reward`): its slots, what it converges to, its backends, its links and its refusals."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import one_line_error

from dgtd.algorithms import make_algorithm
from dgtd.algorithms.actor import SoftmaxActor
from dgtd.algorithms.team_reward import neighbourhood_slots
from dgtd.channels import Arcs, Lossy
from dgtd.graphs import topologies
from dgtd.graphs.random import random_edges
from dgtd.problems import team
from dgtd.run.learn import LearnSettings, learn

DGTD = {"alpha0": 1.0, "beta": 100.0}


def test_an_agents_slots_are_itself_then_its_neighbours_padded_to_the_largest_degree():
    """A path 0 - 1 - 2: agent 1 hears 0 and 2 (K = 3), the ends one each, their last slot padding."""
    arcs = Arcs.of(np.array([[0, 1], [1, 2]]), 3)
    members, arc_ids, valid = neighbourhood_slots(arcs.dst, arcs.src, np.arange(3))
    assert valid.tolist() == [[True, True, False], [True, True, True], [True, True, False]]
    assert members[valid].tolist() == [0, 1, 1, 0, 2, 2, 1]
    assert (arc_ids[:, 0] == -1).all()
    for i, k in zip(*np.nonzero(valid[:, 1:])):  # each neighbour's slot is the arc from it into the agent
        a = arc_ids[i, k + 1]
        assert (arcs.dst[a], arcs.src[a]) == (i, members[i, k + 1])
    rank = neighbourhood_slots(arcs.dst, arcs.src, np.array([2]))  # an agent's rows alone, as a rank holds them
    assert rank[0].tolist() == [[2, 1]] and rank[2].tolist() == [[True, True]]


def conditional_means(mdp: team.TeamMDP) -> np.ndarray:
    """E[r_k | s, a_i] (N_i, N_k, S, 2) under uniform policies: R_k(s, a) averaged over the joint actions with a_i."""
    N = mdp.n_agents
    joint = np.stack(np.unravel_index(np.arange(2**N), (2,) * N), axis=-1)  # (2^N, N)
    return np.stack([
        np.stack([mdp.R[:, :, joint[:, i] == c].mean(axis=-1) for c in (0, 1)], axis=-1) for i in range(N)
    ])  # fmt: skip


def test_each_slot_learns_its_members_mean_reward_given_the_agents_own_action_over_lossy_links():
    """Actors held still (uniform policies) on pull-away, the ring, 30 % of messages lost: after 10 000 steps every
    slot's table is E[r_k | s, a_i] of its member k (exact, by averaging the joint table over the others' actions),
    learnt only from the rewards heard. Tolerance 0.15 on the mean over 16 seeds: a slot's running mean at this
    step (`mean_step` 0.1 a visit, a third of the visits lost) has a standard deviation of about 0.13 a seed for
    rewards that spread 0.5 given (s, a_i), 0.034 over the seeds: over 4 of them."""
    mdp, T = team.pull_away(), 10_000
    ring = topologies.ring(4)
    arcs = Arcs.of(ring.edges, 4)
    settings = LearnSettings(T, 16, checkpoints=1, team_reward="neighbourhood", backend="numpy")
    snaps: list = []
    learn(
        mdp, ring, make_algorithm("dgtd", **DGTD), SoftmaxActor(warmup=T), settings, Lossy(np.full(arcs.n_arcs, 0.3)),
        checkpoint_every=T - 1, on_checkpoint=snaps.append,
    )  # fmt: skip
    lam = snaps[0]["lam"].mean(axis=0)  # (N, K, A, S)
    members, _, valid = neighbourhood_slots(arcs.dst, arcs.src, np.arange(4))
    exact = conditional_means(mdp)  # (N, N, S, A)
    for i, k in zip(*np.nonzero(valid)):
        np.testing.assert_allclose(lam[i, k], exact[i, members[i, k]].T, atol=0.15)


def run(backend: str, iterations: int = 600, batch: int = 1, loss: float = 0.0, seeds: int = 2, graph=None):
    mdp = team.pull_away()
    net = random_edges(topologies.ring(4), 0.8) if graph is None else graph
    channel = None if loss == 0 else Lossy(np.full(Arcs.of(net.base.edges, 4).n_arcs, loss))
    settings = LearnSettings(
        iterations, seeds, checkpoints=4, batch=batch, backend=backend, team_reward="neighbourhood"
    )
    return learn(mdp, net, make_algorithm("dgtd", **DGTD), SoftmaxActor(), settings, channel)


@pytest.mark.parametrize("batch, loss", [(1, 0.3), (3, 0.0)])
def test_compiled_and_jax_learners_with_the_neighbourhood_estimate_are_the_numpy_ones(batch, loss):
    """The estimate's arithmetic is NumPy's on every backend; the critics' and actors' steps the kernel's (numba) or
    JAX's: 1e-12 relative to 1 + |x| (as `test_learn.test_compiled_and_jax_learners_are_the_numpy_learners`)."""
    pytest.importorskip("jax")
    numpy, *others = (run(b, batch=batch, loss=loss) for b in ("numpy", "numba", "jax"))
    close = lambda x, y: np.testing.assert_array_less(np.abs(x - y) / (1 + np.abs(x)), 1e-12)  # noqa: E731
    for other in others:
        close(numpy.policies, other.policies)
        close(numpy.critic, other.critic)
        for name, values in numpy.metrics.items():
            finite = np.isfinite(values)
            close(values[finite], other.metrics[name][finite])
        assert (numpy.bits == other.bits).all() and (numpy.bits > 0).all()


def test_networked_learners_of_their_neighbourhood_find_the_teams_best_action():
    """pull-away on the ring (each link up w.p. 0.8), 20 000 steps, 4 seeds: an agent's neighbourhood misses one of
    the three others, whose loss (2/3 of a deviation) it does not see, yet deviating still costs its neighbourhood
    1 - 2 (2/3) < 0, a third of what it costs the team: every seed puts at least 0.85 on every agent's part of the
    best action (measured 0.893, 0.980, 0.984, 0.984: slower than Zhang et al.'s regression's 0.992-0.995)."""
    result = run("numba", iterations=20_000, seeds=4)
    assert result.metrics["best_probability"][-1].min() >= 0.85
    assert result.metrics["return"][-1].min() > 1.95


@pytest.mark.parametrize(
    "args, words",
    [
        (["--team-reward", "mean"], ["--team-reward", "mean", "'regression', 'neighbourhood'"]),
        (["--team-reward", "neighbourhood", "--actor", "independent"], ["--team-reward", "independent actors"]),
        (["--team-reward", "neighbourhood", "--values", "action"], ["--team-reward", "--values action"]),
        (["--team-reward", "neighbourhood", "--delay", "2"], ["neighbourhood", "not delay"]),
    ],
)
def test_a_neighbourhood_estimate_it_cannot_keep_is_one_line(run_cli, tmp_path, args, words):
    one_line_error(*run_cli("learn", "pull-away", *args, "-T", 10, "--no-progress", "--out", tmp_path / "o"), *words)
