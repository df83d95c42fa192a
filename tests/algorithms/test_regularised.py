"""With the regulariser rho > 0 the saddle point moves (the paper's remark after Proposition 7): DGTD converges to the
regularised w of each agent, so errors are measured against that, and its distance from w* is reported."""

from __future__ import annotations

import numpy as np
from numpy.testing import assert_allclose

from dgtd.algorithms import make_algorithm
from dgtd.graphs import topologies
from dgtd.graphs.random import random_edges
from dgtd.problems import exact
from dgtd.run.loop import RunSettings, run
from dgtd.run.results import summary
from dgtd.sources.model import Sampling


def test_errors_are_measured_against_the_regularised_saddle_point(small_problem):
    network = random_edges(topologies.ring(small_problem.n_agents), 1.0)
    algorithm = make_algorithm("dgtd", rho=0.5, alpha0=1.0, beta=100.0)
    result = run(small_problem, network, algorithm, Sampling(), RunSettings(iterations=200, seeds=2, checkpoints=4))
    m = exact.Moments(small_problem)
    w_rho = exact.saddle_point(m, network.mean_laplacian(), algorithm.kappa, 0.5).w
    assert_allclose(result.w_ref, w_rho)
    assert_allclose(result.w_star, exact.w_star(m))  # w* of the problem is still reported
    expected = np.abs(result.w_last - w_rho).max(-1) / np.abs(w_rho).max()
    assert_allclose(result.agent_error_last[-1], expected)
    assert_allclose(result.metrics["error_last"][-1], expected.max(-1))
    shift = np.abs(w_rho - exact.w_star(m)).max() / np.abs(exact.w_star(m)).max()
    assert shift > 1e-3  # the two differ: the test tells them apart
    s = summary(result, {})
    assert s["regularisation_shift"] == result.info["regularisation_shift"] and np.isclose(
        s["regularisation_shift"], shift
    )
    assert_allclose(s["error_last"], expected)


def test_without_the_regulariser_the_reference_is_w_star(small_problem):
    network = random_edges(topologies.ring(small_problem.n_agents), 1.0)
    result = run(small_problem, network, make_algorithm("dgtd"), Sampling(), RunSettings(iterations=50, checkpoints=2))
    assert_allclose(result.w_ref, np.broadcast_to(result.w_star, result.w_ref.shape))
    assert result.info["regularisation_shift"] == 0.0
