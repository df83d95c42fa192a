"""Decentralised TDC with gradient tracking (`dgtd.algorithms.tdc_tracking`): its exact fixed point and its convergence
off-policy (its tracker: tests/algorithms/test_baselines.py, with TD tracking's)."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose
from test_baselines import expected, small_mdp

from dgtd.algorithms import TDCTracking
from dgtd.algorithms.tdc_tracking import TDCTrackingState
from dgtd.graphs import topologies
from dgtd.graphs.random import random_edges
from dgtd.problems import exact
from dgtd.run.loop import RunSettings, run
from dgtd.sources.model import Sampling


@pytest.mark.parametrize("off_policy", [False, True])
def test_consensus_on_w_star_is_its_exact_fixed_point(off_policy):
    """At w_i = w*, theta_i = M^-1 (b_i - A w*) (TDC's auxiliary at its fast-timescale limit), z_i = 0 and g_i = the
    mean TDC direction there, b_i - A w* - (M - A^T) theta_i, the expected step changes nothing: E[z'] = W 0 +
    E[g_i] - g_i = 0, E[w'] = W (1 w*) = 1 w*, E[theta'] = theta + beta (b_i - A w* - M theta_i) = theta. Exact
    expectations over every outcome of a 5-state MDP, on- and off-policy (where TD's fixed point is w* too, but TD
    may diverge)."""
    p = small_mdp(off_policy, n_agents=4)
    m = exact.Moments(p)
    graph = topologies.from_edges(4, [(0, 1), (1, 2), (2, 3), (0, 2)])
    w_star = exact.w_star(m)
    w = np.broadcast_to(w_star, (1, 4, 3)).copy()
    theta = np.linalg.solve(m.M, (m.b - w_star @ m.A.T).T).T[None]  # (1, N, q)
    g = (m.b - w_star @ m.A.T)[None] - theta @ (m.M - m.A.T).T
    assert np.abs(g).max() > 1e-3  # each agent's direction is not zero; their mean is
    point = TDCTrackingState(theta=theta, g=g, w=w, z=np.zeros_like(w))
    e = expected(p, TDCTracking(), point, graph)
    assert_allclose(e.w, w, atol=1e-12)
    assert_allclose(e.theta, theta, atol=1e-12)
    assert_allclose(e.z, 0.0, atol=1e-12)
    moved = expected(p, TDCTracking(), point._replace(w=w + 0.1), graph)
    assert np.abs(moved.w - (w + 0.1)).max() > 1e-3


@pytest.mark.parametrize("backend", [pytest.param("numpy", marks=pytest.mark.slow), "numba"])  # the reference: slow
def test_it_reaches_w_star_off_policy_on_random_links(backend):
    """A 5-state off-policy MDP, 3 agents on a ring whose links are up with probability 0.7, alpha_k = 3 / sqrt(k +
    10) over 100,000 steps: the tail averages of 4 seeds within 2 % of w* (max-norm), every agent.

    Tolerance: the measured worst error over 8 seeds (base seeds 0 and 1) is 0.28 %; 2 % is seven times that and
    below the 7.4 % distance from w* to the nearest agent's own fixed point A^-1 b_i, so a wrong average fails."""
    p = small_mdp(True, n_agents=3)
    r = run(
        p,
        random_edges(topologies.ring(3), 0.7),
        TDCTracking(alpha0=3.0, beta=10.0),
        Sampling(),
        RunSettings(iterations=100_000, seeds=4, checkpoints=5, backend=backend),
    )
    assert exact.relative_error(r.w_tail, r.w_star).max() < 0.02
    m = exact.Moments(p)
    own = np.linalg.solve(m.A, m.b.T).T
    assert exact.relative_error(own, r.w_star).min() > 0.07
