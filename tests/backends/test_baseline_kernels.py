"""The compiled baseline kernels give the NumPy reference's numbers on the same seeds (to 1e-9)."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from dgtd.algorithms import make_algorithm
from dgtd.backends.compiled import STEPS
from dgtd.graphs import topologies
from dgtd.graphs.random import random_edges
from dgtd.problems import tasks
from dgtd.run.loop import RunSettings, run
from dgtd.sources.model import Sampling

# every algorithm with a compiled step but DGTD (whose own tests are in test_run.py), from the registry
BASELINES = tuple(name for name in STEPS if name != "dgtd")

# (off-policy, edge probability, sampling mode, shared trajectory)
SETTINGS = [
    (False, 1.0, "iid", False),
    (False, 0.6, "markov", True),
    (True, 0.6, "iid", False),
    (True, 1.0, "markov", False),
    (True, 0.6, "markov", True),
]


def problem(off_policy: bool):
    return tasks.random_mdp(n_agents=5, off_policy=off_policy, seed=7, n_states=6, n_actions=3, n_features=4, gamma=0.9)


@pytest.mark.parametrize("name", BASELINES)
@pytest.mark.parametrize("off_policy, edge_prob, mode, shared", SETTINGS)
def test_numba_matches_numpy(name, off_policy, edge_prob, mode, shared):
    p = problem(off_policy)
    net = random_edges(topologies.ring_with_chords(5, 2), edge_prob)
    alg = make_algorithm(name, alpha0=0.05, beta=10.0)
    out = {}
    for backend in ("numpy", "numba"):
        st = RunSettings(iterations=700, seeds=3, seed=11, checkpoints=5, block_size=256, backend=backend)
        out[backend] = run(p, net, alg, Sampling(mode=mode, shared=shared), st)
    a, b = out["numpy"], out["numba"]
    scale = max(1.0, float(np.abs(a.w_last).max()))
    assert np.all(a.info["diverged_at"] < 0)
    for key in a.final_state:
        assert_allclose(b.final_state[key], a.final_state[key], rtol=1e-9, atol=1e-9 * scale)
    assert_allclose(b.w_avg, a.w_avg, rtol=1e-9, atol=1e-9 * scale)
    assert_allclose(b.w_tail, a.w_tail, rtol=1e-9, atol=1e-9 * scale)
    for key in a.metrics:
        assert_allclose(b.metrics[key], a.metrics[key], rtol=1e-9, atol=1e-12)
    for key in a.info["counts"]:
        assert_allclose(b.info["counts"][key], a.info["counts"][key], rtol=0, atol=0)
    assert np.abs(a.w_last).max() > 0  # the runs moved


@pytest.mark.parametrize("name", ["td0", "consensus-td0", "pd-td"])
def test_both_backends_stop_a_diverging_run_at_the_same_step(name):
    """Off-policy TD on Baird's counterexample: both backends report the same divergence step, no exception."""
    p = tasks.baird(n_agents=3)
    net = random_edges(topologies.ring(3), 0.7)
    alg = make_algorithm(name, alpha0=1.0, beta=100.0)
    res = [
        run(p, net, alg, Sampling(), RunSettings(iterations=6000, seeds=2, checkpoints=10, block_size=512, backend=b))
        for b in ("numpy", "numba")
    ]
    assert np.all(res[0].info["diverged_at"] > 0)
    assert np.array_equal(res[0].info["diverged_at"], res[1].info["diverged_at"])
    assert_allclose(res[0].metrics["error_last"], res[1].metrics["error_last"], rtol=1e-9, equal_nan=True)


@pytest.mark.parametrize("name", ("dgtd", "td-tracking") + BASELINES)
@pytest.mark.parametrize("mode", ["iid", "markov"])
def test_an_episodic_task_discounts_the_same_on_both_backends(name, mode):
    """The Boyan chain's terminal state: gamma(s, s') = 0 into and out of it, in the reference and in every kernel."""
    p = tasks.boyan(n_agents=4, n_states=8)
    net = random_edges(topologies.ring(4), 0.7)
    alg = make_algorithm(name, alpha0=0.05, beta=10.0)
    out = {}
    for backend in ("numpy", "numba"):
        st = RunSettings(iterations=600, seeds=2, seed=3, checkpoints=4, block_size=128, backend=backend)
        out[backend] = run(p, net, alg, Sampling(mode=mode), st)
    a, b = out["numpy"], out["numba"]
    scale = max(1.0, float(np.abs(a.w_last).max()))
    for key in a.final_state:
        assert_allclose(b.final_state[key], a.final_state[key], rtol=1e-9, atol=1e-9 * scale)
    assert np.abs(a.w_last).max() > 0


def test_td0_on_the_episodic_boyan_chain_reaches_the_published_solution():
    """13 states, gamma 1: the values are linear and w* = (-24, -16, -8, 0) exactly. Centralised TD(0) from 8
    agents' samples for 2e5 steps, harmonic steps: the tail average within 2 % of |w*|_inf (the run's own spread
    over 4 seeds is well under 1 %). With gamma = 1 the return is finite only because it ends at the terminal."""
    p = tasks.boyan(n_agents=8, n_states=13, gamma=1.0)
    net = random_edges(topologies.ring(8), 1.0)
    res = run(
        p,
        net,
        make_algorithm("td0", alpha0=20.0, beta=100.0, schedule="harmonic"),
        Sampling(),
        RunSettings(iterations=200_000, seeds=4, checkpoints=5),
    )
    assert_allclose(res.w_star, [-24.0, -16.0, -8.0, 0.0], atol=1e-9)
    assert np.abs(res.w_tail - res.w_star).max() < 0.02 * 24
