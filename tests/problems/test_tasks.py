"""The benchmark tasks: exact solutions checked by hand, agents' rewards, and what the model refuses."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from numpy.testing import assert_allclose

from dgtd.algorithms import make_algorithm
from dgtd.errors import DgtdInputError
from dgtd.graphs import topologies
from dgtd.graphs.random import random_edges
from dgtd.problems import exact, tasks
from dgtd.problems.model import chain_period, make_problem
from dgtd.run.loop import RunSettings, run
from dgtd.scenarios import SCENARIOS, get_scenario
from dgtd.sources.model import Sampling


def test_baird_w_star_by_hand():
    """The task's reward is 0, so the values Phi w* are 0, and w* is w0's component along the null space of
    Phi, spanned by n = (1, 1, 1, 1, 1, 1, 4, -2) (2 n_i + n_8 = 0 for the upper states, n_7 + 2 n_8 = 0 for the
    lower one): w* = (n.w0 / n.n) n = (44 / 26) n = (22/13) (1, 1, 1, 1, 1, 1, 4, -2)."""
    p = tasks.baird(n_agents=4)
    m = exact.Moments(p)
    n = np.array([1, 1, 1, 1, 1, 1, 4, -2], dtype=float)
    assert_allclose(p.Phi @ n, 0.0, atol=0)
    assert_allclose(exact.w_star(m), 22.0 / 13.0 * n, atol=1e-12)
    assert_allclose(p.Phi @ exact.w_star(m), 0.0, atol=1e-12)
    assert_allclose(exact.value_function(m), 0.0, atol=1e-12)
    assert_allclose(m.d, np.full(7, 1 / 7), atol=1e-14)  # the behaviour chain's rows are all (1/7, ..., 1/7)
    assert exact.mspbe(m, exact.w_star(m)) < 1e-25
    assert not m.full_rank and p.off_policy
    # the task: ratios 0 (dashed) and 7 (solid); phi(upper 1) = 2 e_1 + e_8; phi(lower) = e_7 + 2 e_8; gamma 0.99
    assert_allclose(p.ratio, np.tile([0.0, 7.0], (7, 1)))
    assert_allclose(p.Phi[0], [2, 0, 0, 0, 0, 0, 0, 1])
    assert_allclose(p.Phi[6], [0, 0, 0, 0, 0, 0, 1, 2])
    assert p.gamma == 0.99 and tuple(p.w0) == (1, 1, 1, 1, 1, 1, 10, 1)
    # agents' rewards average to the task's (zero) and are not zero
    assert_allclose(p.R_sample.mean(axis=0), 0.0, atol=1e-15)
    assert np.all(np.abs(p.R).max(axis=1) > 0.1)


def test_baird_exact_quantities_with_dependent_features_satisfy_the_kkt_equations():
    p = tasks.baird(n_agents=4)
    m = exact.Moments(p)
    L = topologies.ring(4).laplacian()
    sp = exact.saddle_point(m, L, kappa=1.0)
    assert max(exact.kkt_residuals(m, L, 1.0, 0.0, sp).values()) < 1e-9
    assert np.all(np.isfinite(list(vars(exact.lemma_bounds(m, L, 2)).values())))


def test_boyan_w_star_by_hand():
    """The Boyan chain built here state by state, d by power iteration, A and b as sums over transitions:
    the same w* as the library's linear algebra. Features checked at hand-computed points."""
    S = 14
    P = np.zeros((S, S))
    r = np.zeros(S)
    for s in range(12):  # states 0..11: one or two steps ahead, reward -3
        P[s, s + 1] += 0.5
        P[s, s + 2] += 0.5
        r[s] = -3.0
    P[12, 13], r[12] = 1.0, -2.0  # the state before the terminal one
    P[13, 0], r[13] = 1.0, 0.0  # terminal state: restart
    d = np.full(S, 1.0 / S)
    for _ in range(20_000):
        d = d @ P
    d = 0.5 * (d + d @ P)  # the chain is aperiodic; average two steps to kill any residual oscillation
    c, a = np.linspace(1, 14, 4), 13.0 / 3.0
    Phi = np.array([[max(0.0, 1 - abs(s + 1 - cj) / a) for cj in c] for s in range(S)])
    assert_allclose(Phi[0], [1, 0, 0, 0])
    assert_allclose(Phi[13], [0, 0, 0, 1])
    assert_allclose(Phi[4], [1 / 13, 12 / 13, 0, 0])  # |5 - 1| / (13/3) = 12/13, |5 - 16/3| / (13/3) = 1/13
    # state 13 is terminal: no discount into it or out of it (the restart), gamma(s, t) = 0.95 c(s) c(t)
    gamma = lambda s, t: 0.95 * (s != 13) * (t != 13)  # noqa: E731
    A = sum(d[s] * P[s, t] * np.outer(Phi[s], Phi[s] - gamma(s, t) * Phi[t]) for s in range(S) for t in range(S))
    b = sum(d[s] * r[s] * Phi[s] for s in range(S))
    w_hand = np.linalg.solve(A, b)

    p = tasks.boyan(n_agents=6)
    m = exact.Moments(p)
    assert_allclose(p.P, P)
    assert_allclose(p.Phi, Phi, atol=1e-15)
    assert_allclose(p.R.mean(axis=0), r, atol=1e-12)
    assert_allclose(m.d, d, atol=1e-10)
    assert_allclose(exact.w_star(m), w_hand, rtol=1e-9)
    assert np.all(p.R.std(axis=0) > 0.1)  # the agents' rewards differ at every state


def test_reward_split_keeps_means_and_bounds():
    rng = np.random.default_rng(0)
    mean = rng.uniform(size=(20, 3))
    r = tasks.split_rewards(mean, 7, rng, low=0.0, high=1.0)
    assert r.shape == (7, 20, 3)
    assert_allclose(r.mean(axis=0), mean, atol=1e-15)
    assert r.min() >= 0.0 and r.max() <= 1.0
    assert np.all(r.std(axis=0) > 0)


def test_random_mdp_is_seeded_and_on_and_off_policy():
    a, b = tasks.random_mdp(seed=4, n_states=30, n_features=10), tasks.random_mdp(seed=4, n_states=30, n_features=10)
    assert_allclose(a.P, b.P) and not a.off_policy
    off = tasks.random_mdp(seed=4, n_states=30, n_features=10, off_policy=True)
    assert off.off_policy and np.all(off.ratio > 0)
    assert_allclose(off.P, a.P)  # the same MDP and target policy; only the behaviour differs
    full = tasks.random_mdp()
    assert (full.n_states, full.n_actions, full.n_features, full.gamma) == (400, 10, 200, 0.95)
    assert_allclose(full.Phi[:, -1], 1.0)


def test_garnet_is_ergodic_with_the_asked_branching():
    p = tasks.garnet(n_states=25, branching=2, n_agents=4, n_features=5, seed=3)
    assert np.all((p.P > 0).sum(axis=1) == 2)
    assert chain_period(p.P) == 1
    assert p.n_agents == 4 and p.n_features == 5
    with pytest.raises(DgtdInputError, match="branching"):
        tasks.garnet(n_states=5, branching=9)


SIMULATED = {"mpe-spread"}  # no model: its estimated reference is tested in tests/sources/test_env_source.py


def test_every_scenario_builds_and_solves():
    for name in set(SCENARIOS) - SIMULATED:
        sc = get_scenario(name)
        m = exact.Moments(sc.problem)
        w = exact.w_star(m)
        assert np.all(np.isfinite(w)) and exact.mspbe(m, w) < 1e-20
        assert sc.network.n_nodes == sc.problem.n_agents


def test_signed_rewards_and_dependent_features_only_on_request():
    P = np.array([[0.5, 0.5], [0.5, 0.5]])
    with pytest.raises(DgtdInputError, match=">= 0"):
        make_problem(P, [[-1.0, 1.0]], np.eye(2), 0.9)
    p = make_problem(P, [[-1.0, 1.0]], np.eye(2), 0.9, signed_rewards=True)
    assert p.sigma == 1.0
    with pytest.raises(DgtdInputError, match="reward noise"):
        make_problem(P, [[-1.0, 1.0]], np.eye(2), 0.9, signed_rewards=True, reward_noise="bernoulli")
    with pytest.raises(DgtdInputError, match="full column rank"):
        make_problem(P, [[1.0, 1.0]], np.ones((2, 3)), 0.9)
    with pytest.raises(DgtdInputError, match="w0"):
        make_problem(P, [[1.0, 1.0]], np.eye(2), 0.9, w0=[1.0, 2.0, 3.0])
    # noise switched on later (as `dgtd run --reward-noise` does) is refused by the run
    noisy = replace(tasks.boyan(n_agents=2), reward_noise="uniform")
    with pytest.raises(DgtdInputError, match="negative mean rewards"):
        run(noisy, random_edges(topologies.path(2), 1.0), make_algorithm("td0"), Sampling(), RunSettings(iterations=5))


def test_boyan_chain_has_the_published_values():
    """Boyan (2002), Dann et al. (2014): the last state is terminal (value 0) and the return ends there. With 14
    states and gamma 0.95 the true values run from -21.479 through -3.950 and -2 to 0; with 13 states and gamma 1
    they are linear, -2 per state from the end, and the 4 triangular features represent them: w* = (-24, -16, -8, 0)."""
    from dgtd.problems import exact
    from dgtd.problems.tasks import boyan

    J = exact.value_function(exact.Moments(boyan()))
    assert J[0] == pytest.approx(-21.479, abs=5e-4)
    assert J[-3:] == pytest.approx([-3.95, -2.0, 0.0], abs=1e-12)
    m13 = exact.Moments(boyan(n_states=13, gamma=1.0))
    assert exact.value_function(m13) == pytest.approx(-2.0 * np.arange(12, -1, -1), abs=1e-9)
    assert exact.w_star(m13) == pytest.approx([-24.0, -16.0, -8.0, 0.0], abs=1e-9)


def test_an_episodic_task_needs_its_terminal_states_to_be_reached_with_gamma_one():
    from dgtd.errors import DgtdInputError
    from dgtd.problems.model import make_problem

    P = np.array([[0.0, 1.0], [1.0, 0.0]])
    with pytest.raises(DgtdInputError, match="strictly between 0 and 1"):
        make_problem(P, np.ones((1, 2)), np.eye(2), 1.0)
    make_problem(P, np.ones((1, 2)), np.eye(2), 1.0, terminal=[0, 1])
    with pytest.raises(DgtdInputError, match="terminal must be 2 flags"):
        make_problem(P, np.ones((1, 2)), np.eye(2), 0.9, terminal=[0, 2])
