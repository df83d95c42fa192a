"""Exact quantities against closed forms and hand-computed cases."""

from fractions import Fraction

import numpy as np
import pytest
from numpy.testing import assert_allclose

from dgtd.graphs import topologies
from dgtd.graphs.random import laplacian_pinv, random_edges
from dgtd.problems import exact
from dgtd.problems.generators import random_mdp_problem, random_problem
from dgtd.problems.model import make_problem
from dgtd.scenarios import get_scenario


def test_w_star_two_state_chain_by_hand():
    # P = [[1/2, 1/2], [1/5, 4/5]], phi = (1, 2), gamma = 1/2, agents' rewards (2, 0) and (0, 0): mean r = (1, 0).
    # d solves d1/2 + d2/5 = d1: d = (2/7, 5/7).  P phi = (3/2, 9/5).
    # A = d1 * 1 * (1 - 3/4) + d2 * 2 * (2 - 9/10) = 1/14 + 11/7 = 23/14;  b = d1 * 1 * 1 = 2/7;  w* = b / A = 4/23.
    d1, d2 = Fraction(2, 7), Fraction(5, 7)
    A = d1 * 1 * (1 - Fraction(1, 2) * Fraction(3, 2)) + d2 * 2 * (2 - Fraction(1, 2) * Fraction(9, 5))
    w_hand = (d1 * 1) / A
    assert w_hand == Fraction(4, 23)
    p = make_problem([[0.5, 0.5], [0.2, 0.8]], [[2.0, 0.0], [0.0, 0.0]], [[1.0], [2.0]], 0.5)
    m = exact.Moments(p)
    assert_allclose(m.d, [2 / 7, 5 / 7], rtol=1e-12)
    assert_allclose(exact.w_star(m), [4 / 23], rtol=1e-12)


def test_paper_example_1_w_star():
    m = exact.Moments(get_scenario("paper-example-1").problem)
    assert_allclose(exact.w_star(m), [15.90, 21.03], atol=5e-3)


def test_stationary_distribution_is_stationary(rng):
    p = random_problem(9, 2, 3, rng)
    d = exact.stationary_distribution(p.P)
    assert_allclose(d @ p.P, d, atol=1e-13)
    assert d.min() > 0 and abs(d.sum() - 1) < 1e-13


def test_w_star_of_mean_reward_is_mean_of_agents_w_star(small_problem):
    m = exact.Moments(small_problem)
    per_agent = np.linalg.solve(m.A, m.b.T).T
    assert_allclose(exact.w_star(m), per_agent.mean(axis=0), rtol=1e-10)


def test_mspbe_vanishes_at_w_star_only(small_problem, rng):
    m = exact.Moments(small_problem)
    w = exact.w_star(m)
    assert abs(exact.mspbe(m, w)) < 1e-20
    assert exact.mspbe(m, w + 0.1 * rng.standard_normal(w.shape)) > 1e-6


def test_mspbe_matches_projection_definition(small_problem, rng):
    # 1/2 |Pi(r + gamma P Phi w) - Phi w|_D^2 with Pi = Phi (Phi^T D Phi)^-1 Phi^T D, eq. (GDD(0)-loss).
    p, m = small_problem, exact.Moments(small_problem)
    w = rng.standard_normal(p.n_features)
    D = np.diag(m.d)
    Pi = p.Phi @ np.linalg.solve(p.Phi.T @ D @ p.Phi, p.Phi.T @ D)
    e = Pi @ (p.R.mean(0) + p.gamma * p.P @ p.Phi @ w) - p.Phi @ w
    assert_allclose(exact.mspbe(m, w), 0.5 * e @ D @ e, rtol=1e-10)


def test_tabular_w_star_is_true_value(rng):
    p = random_problem(7, 3, 7, rng, gamma=0.9)
    m = exact.Moments(p)
    assert_allclose(exact.w_star(m), np.linalg.solve(np.eye(7) - 0.9 * p.P, p.R.mean(0)), rtol=1e-10)
    assert_allclose(exact.w_star(m), exact.value_function(m), rtol=1e-10)


@pytest.mark.parametrize("kappa", [0.0, 1.0, 3.5])
@pytest.mark.parametrize("off_policy", [False, True])
def test_saddle_point_satisfies_kkt(kappa, off_policy, rng):
    if off_policy:
        p = random_mdp_problem(6, (2, 2, 2), 4, rng)
    else:
        p = random_problem(8, 5, 4, rng)
    net = random_edges(topologies.ring(p.n_agents), rng.uniform(0.2, 1.0, p.n_agents))
    m, L = exact.Moments(p), net.mean_laplacian()
    sp = exact.saddle_point(m, L, kappa)
    res = exact.kkt_residuals(m, L, kappa, 0.0, sp)
    assert max(res.values()) < 1e-9, res
    assert np.all(sp.v == 0)
    assert_allclose(sp.w, np.tile(exact.w_star(m), (p.n_agents, 1)))
    # theta* sums to zero over agents, so bar-B^T theta* lies in the range of bar-L (prop:saddle-point-mu).
    assert_allclose(sp.theta.sum(0), 0, atol=1e-10)


def test_theta_star_sign_matters(small_problem):
    # The statement of prop:stationary-points carries the opposite sign; that point violates the first KKT equation.
    m = exact.Moments(small_problem)
    L = topologies.complete(small_problem.n_agents).laplacian()
    sp = exact.saddle_point(m, L, 1.0)
    flipped = exact.SaddlePoint(-sp.theta, sp.v, -sp.mu, sp.w)
    assert exact.kkt_residuals(m, L, 1.0, 0.0, flipped)["theta"] > 1e-3


def test_regularised_saddle_point(small_problem):
    m = exact.Moments(small_problem)
    L = topologies.path(small_problem.n_agents).laplacian()
    for rho in (1e-1, 1e-4):
        sp = exact.saddle_point(m, L, 1.0, rho)
        assert max(exact.kkt_residuals(m, L, 1.0, rho, sp).values()) < 1e-8
    # As rho -> 0 the regularised saddle point's w approaches 1 kron w* (the paper: "slightly altered").
    assert_allclose(sp.w, np.tile(exact.w_star(m), (small_problem.n_agents, 1)), rtol=1e-2, atol=1e-3)


def test_laplacian_pinv_formula(rng):
    G = topologies.ring_with_chords(7, 3)
    L = G.laplacian(rng.uniform(0.1, 1, G.n_edges))
    assert_allclose(laplacian_pinv(L), np.linalg.pinv(L), atol=1e-12)


def test_lemma_bounds_contain_the_saddle_point(rng):
    for _ in range(5):
        p = random_problem(int(rng.integers(3, 9)), int(rng.integers(2, 6)), 2, rng, gamma=rng.uniform(0.5, 0.95))
        L = topologies.ring(p.n_agents).laplacian()
        m = exact.Moments(p)
        c = exact.lemma_bounds(m, L, 2)
        sp = exact.saddle_point(m, L)
        assert np.abs(sp.w).max() <= c.w
        assert np.abs(sp.theta).max() <= c.theta
        assert np.abs(sp.mu).max() <= c.mu


def test_consensus_and_relative_error():
    W = np.array([[[1.0, 2.0], [3.0, 2.0]]])
    assert_allclose(exact.consensus_error(W), [2.0])  # mean (2, 2): 1 + 1
    assert_allclose(exact.relative_error(W, np.array([2.0, 2.0])), [[0.5, 0.5]])


def test_sparse_laplacian_paths_match_dense(rng, monkeypatch):
    # Above DENSE_N agents mu* comes from conjugate gradients and sizes C_mu; force those
    # paths on a small graph and compare with the dense formulas.
    p = random_problem(6, 30, 3, rng)
    G = topologies.ring_with_chords(30, 7)
    w = rng.uniform(0.2, 1.0, G.n_edges)
    m, L, Ls = exact.Moments(p), G.laplacian(w), G.laplacian_sparse(w)
    assert_allclose(Ls.toarray(), L)
    dense_mu = exact.mu_star(m, L)
    monkeypatch.setattr(exact, "DENSE_N", 10)
    assert_allclose(exact.mu_star(m, Ls), dense_mu, rtol=1e-9, atol=1e-11)
    sp = exact.saddle_point(m, Ls, 1.0)
    assert max(exact.kkt_residuals(m, Ls, 1.0, 0.0, sp).values()) < 1e-9
    # c_mu is then |mu*|_inf itself, which the lemma's (dense) bound over-estimates.
    c = exact.lemma_bounds(m, Ls, 4)
    assert_allclose(c.mu, np.abs(dense_mu).max(), rtol=1e-9)
    monkeypatch.setattr(exact, "DENSE_N", 2000)
    assert exact.lemma_bounds(m, L, 4).mu >= c.mu


def _iid_problem():
    """Three states drawn i.i.d. from d = (0.5, 0.25, 0.25) (every row of P is d), features (1, 0), (0, 1), (1, 1),
    gamma 0.5, mean rewards (1, 0, 0) split over two agents: J = r + 0.5 d.J 1 = (1.5, 0.5, 0.5)."""
    from dgtd.problems.model import make_problem

    d = np.array([0.5, 0.25, 0.25])
    return make_problem(
        np.tile(d, (3, 1)), np.array([[2.0, 0, 0], [0, 0, 0]]), np.array([[1.0, 0], [0, 1], [1, 1]]), 0.5, name="iid"
    )


def test_value_error_is_the_d_weighted_norm_of_the_value_difference():
    """|Phi (w - w_ref)|_d / |Phi w_ref|_d by hand: Phi (1, 0) = (1, 0, 1), norm^2 0.5 + 0.25 = 0.75; Phi (1, 2) =
    (1, 2, 3), norm^2 0.5 + 1 + 2.25 = 3.75; the ratio is sqrt(0.2)."""
    m = exact.Moments(_iid_problem())
    W = np.array([[[2.0, 2.0], [1.0, 2.0]]])  # one seed, two agents: off by (1, 0), and exact
    assert np.allclose(exact.value_error(m, W, np.array([1.0, 2.0])), [[np.sqrt(0.2), 0.0]])


def test_true_value_error_is_measured_against_the_value_function():
    """J = (1.5, 0.5, 0.5); Phi (1, 0) = (1, 0, 1) misses it by (-0.5, -0.5, 0.5): norm^2 0.25 against |J|_d^2 1.25."""
    m = exact.Moments(_iid_problem())
    assert np.allclose(exact.value_function(m), [1.5, 0.5, 0.5])
    assert np.allclose(exact.true_value_error(m, np.array([[1.0, 0.0]])), [np.sqrt(0.2)])


def test_value_error_is_relative_to_the_start_where_the_task_prescribes_one():
    """Baird's values are all zero (|Phi w*|_d = 0): the error is relative to that of its start w0, so the start
    has value error 1."""
    from dgtd.problems.tasks import baird

    p = baird(n_agents=2)
    m = exact.Moments(p)
    w_star = exact.w_star(m)
    assert np.allclose(p.Phi @ w_star, 0.0, atol=1e-9)
    assert np.allclose(exact.value_error(m, np.tile(p.w0, (1, 2, 1)), w_star), 1.0)


def test_rmspbe_is_the_projected_bellman_error_in_the_d_norm():
    """|Pi T(Phi w) - Phi w|_D by projecting explicitly: Pi = Phi M^-1 Phi^T D, T v = r_mean + gamma P v."""
    m = exact.Moments(_iid_problem())
    p = m.problem
    w = np.array([0.3, -1.2])
    D = np.diag(m.d)
    Pi = p.Phi @ np.linalg.solve(m.M, p.Phi.T @ D)
    err = Pi @ (p.R.mean(0) + p.gamma * p.P @ p.Phi @ w) - p.Phi @ w
    assert np.isclose(exact.rmspbe(m, w), np.sqrt(err @ D @ err))


def test_mu_star_is_solved_once_for_the_same_laplacian(rng, monkeypatch):
    """The saddle point and the boxes' bounds both ask for mu* (each with its own copy of the mean Laplacian): above
    DENSE_N agents a solve took 50 s at a million agents, so it is kept for a Laplacian of the same numbers, and
    solved again for another."""
    p = random_problem(6, 30, 3, rng)
    G = topologies.ring_with_chords(30, 7)
    m = exact.Moments(p)
    monkeypatch.setattr(exact, "DENSE_N", 10)
    solves = []
    real = exact.lap_pinv_apply
    monkeypatch.setattr(exact, "lap_pinv_apply", lambda L, Y: solves.append(1) or real(L, Y))
    first = exact.mu_star(m, G.laplacian_sparse(np.ones(G.n_edges)))
    again = exact.mu_star(m, G.laplacian_sparse(np.ones(G.n_edges)))  # another object, the same numbers
    assert again is first and len(solves) == 1
    other = exact.mu_star(m, G.laplacian_sparse(np.full(G.n_edges, 0.5)))
    assert len(solves) == 2 and not np.allclose(other, first)
