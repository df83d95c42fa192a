"""Baselines against their mean-path forms, their fixed points, and DGTD with one agent."""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np
import pytest
from numpy.testing import assert_allclose

from dgtd.algorithms import (
    ALGORITHMS,
    GTD2,
    PDTD,
    TD0,
    TDC,
    ConsensusTD0,
    Local,
    TDCTracking,
    TDTracking,
    make_algorithm,
)
from dgtd.algorithms.consensus_td0 import ConsensusState
from dgtd.algorithms.dgtd import DGTD
from dgtd.algorithms.gtd2 import GTDState
from dgtd.algorithms.pd_td import PDTDState
from dgtd.algorithms.td0 import TD0State
from dgtd.algorithms.td_tracking import TrackingState
from dgtd.channels import Arcs, Perfect
from dgtd.errors import DgtdInputError
from dgtd.graphs import topologies
from dgtd.graphs.random import random_edges
from dgtd.problems import exact, tasks
from dgtd.problems.model import make_problem
from dgtd.run.loop import RunSettings, run
from dgtd.samples import Sample
from dgtd.sources.model import Sampling


def small_mdp(off_policy: bool, n_agents: int = 3, seed: int = 3):
    """A 5-state, 2-action random MDP with 3 features (on- or off-policy), small enough to enumerate."""
    return tasks.random_mdp(
        n_agents=n_agents, off_policy=off_policy, seed=seed, n_states=5, n_actions=2, n_features=3, gamma=0.8
    )


def outcomes(problem):
    """Every (s, a, s') with its probability d(s) beta(a|s) P(s, a, s') under the behaviour model."""
    d = exact.Moments(problem).d
    S, A, _ = problem.P_sample.shape
    s, a, sn = (x.ravel() for x in np.meshgrid(np.arange(S), np.arange(A), np.arange(S), indexing="ij"))
    p = d[s] * problem.P_sample[s, a, sn]
    keep = p > 0
    return s[keep], a[keep], sn[keep], p[keep]


class MatrixInbox:
    """An inbox whose Laplacian is a given matrix (a mean Laplacian): (L x)_i along the agent axis of each message."""

    def __init__(self, L, sent: dict):
        self.L, self.sent = L, sent

    def laplacian(self, name):
        return np.einsum("ij,bjq->biq", self.L, self.sent[name])


def heard(graph, algorithm, state, up=None):
    """What every agent hears of ``algorithm.sends(state)`` over the links of ``graph`` up (B, E) (None: all)."""
    return Perfect().inbox(Arcs.of(graph.edges, graph.n_nodes), algorithm.sends(state), up)


def expected(problem, algorithm, state, graph=None, alpha=0.3):
    """E[algorithm.update(state, sample, inbox, alpha)] exactly: the batch axis enumerates the outcomes, each agent
    observing the same (s, a, s') with its own reward; each agent's update depends on its own sample only, so its
    mean over this batch is its mean over its own samples. ``graph``: every link of it up (None: no messages)."""
    s, a, sn, p = outcomes(problem)
    K = len(p)
    sample = Sample(
        problem.Phi[s][:, None, :],
        problem.Phi[sn][:, None, :],
        problem.R_sample[:, s, a].T,
        problem.ratio[s, a][:, None],
        problem.gamma,
    )
    big = type(state)(*(np.broadcast_to(x, (K,) + x.shape[1:]).copy() for x in state))
    new = algorithm.update(big, sample, None if graph is None else heard(graph, algorithm, big), alpha)
    return type(state)(*(np.einsum("k,k...->...", p, x)[None] for x in new))


def metropolis_laplacian(graph, up) -> np.ndarray:
    """L_W of the links ``up`` (E,) of ``graph``: the inbox's Metropolis aggregate of the identity's rows."""
    eye = np.eye(graph.n_nodes)[None]
    return Perfect().inbox(Arcs.of(graph.edges, graph.n_nodes), {"x": eye}, up[None]).metropolis("x")[0]


@pytest.mark.parametrize("off_policy", [False, True])
def test_mean_paths_of_the_centralised_learners(off_policy):
    """TD(0): b - A w; GTD2: (A^T theta, eta (b - A w - M theta)); TDC: (b - A w - (M - A^T) theta, same)."""
    p = small_mdp(off_policy)
    m = exact.Moments(p)
    rng = np.random.default_rng(0)
    w, th = rng.normal(size=(1, 1, 3)), rng.normal(size=(1, 1, 3))
    alpha, eta = 0.3, 0.7
    b, A, M = m.b_mean, m.A, m.M

    e = expected(p, TD0(), TD0State(w), alpha=alpha)
    assert_allclose(e.w[0, 0] - w[0, 0], alpha * (b - A @ w[0, 0]), atol=1e-12)

    e = expected(p, GTD2(eta=eta), GTDState(w, th), alpha=alpha)
    assert_allclose(e.w[0, 0] - w[0, 0], alpha * A.T @ th[0, 0], atol=1e-12)
    assert_allclose(e.theta[0, 0] - th[0, 0], eta * alpha * (b - A @ w[0, 0] - M @ th[0, 0]), atol=1e-12)

    tdc = TDC(eta=eta)  # two timescales by default: beta_k = eta alpha0 (alpha_k / alpha0)^(2/3)
    e = expected(p, tdc, GTDState(w, th), alpha=alpha)
    assert_allclose(e.w[0, 0] - w[0, 0], alpha * (b - A @ w[0, 0] - (M - A.T) @ th[0, 0]), atol=1e-12)
    beta_k = eta * tdc.alpha0 * (alpha / tdc.alpha0) ** (2 / 3)
    assert_allclose(e.theta[0, 0] - th[0, 0], beta_k * (b - A @ w[0, 0] - M @ th[0, 0]), atol=1e-12)


@pytest.mark.parametrize("off_policy", [False, True])
def test_mean_paths_of_the_distributed_learners(off_policy):
    """local: per-agent GTD2 with b_i; consensus TD(0): -L_W w + alpha (b_i - A w_i) with the Metropolis
    Laplacian L_W; pd-td: alpha (b_i - A w_i - eta L w - eta L mu) and alpha eta L w, on a fixed graph."""
    p = small_mdp(off_policy, n_agents=4)
    m = exact.Moments(p)
    graph = topologies.from_edges(4, [(0, 1), (1, 2), (2, 3), (0, 2)])
    L = graph.laplacian()
    rng = np.random.default_rng(1)
    w, th, mu = (rng.normal(size=(1, 4, 3)) for _ in range(3))
    alpha, eta = 0.3, 0.7
    td_mean = alpha * (m.b - w[0] @ m.A.T)  # alpha (b_i - A w_i) per agent, (N, q)

    e = expected(p, Local(eta=eta), GTDState(w, th), alpha=alpha)
    assert_allclose(e.w[0] - w[0], alpha * th[0] @ m.A, atol=1e-12)
    assert_allclose(e.theta[0] - th[0], eta * alpha * (m.b - w[0] @ m.A.T - th[0] @ m.M), atol=1e-12)

    L_W = metropolis_laplacian(graph, np.ones(graph.n_edges, bool))
    e = expected(p, ConsensusTD0(), ConsensusState(w), graph, alpha)
    assert_allclose(e.w[0] - w[0], -L_W @ w[0] + td_mean, atol=1e-12)

    e = expected(p, PDTD(eta=eta), PDTDState(w, mu), graph, alpha)
    assert_allclose(e.w[0] - w[0], td_mean - alpha * eta * (L @ w[0] + L @ mu[0]), atol=1e-12)
    assert_allclose(e.mu[0] - mu[0], alpha * eta * L @ w[0], atol=1e-12)


def test_pd_td_mean_over_random_links_uses_the_mean_laplacian():
    """Averaged over the 2^E link patterns of a triangle with p_e = (0.3, 0.6, 0.9), the pd-td step is its
    fixed-graph step with the mean Laplacian sum_e p_e L_e (the update is linear in L(k))."""
    graph = topologies.ring(3)
    p_e = np.array([0.3, 0.6, 0.9])
    rng = np.random.default_rng(2)
    w, mu = rng.normal(size=(1, 3, 2)), rng.normal(size=(1, 3, 2))
    sample = Sample(
        rng.uniform(size=(1, 1, 2)), rng.uniform(size=(1, 1, 2)), rng.uniform(size=(1, 3)), np.ones((1, 1)), 0.9
    )
    alg = PDTD(eta=2.0)
    mean_w, mean_mu = 0.0, 0.0
    for up in itertools.product([False, True], repeat=3):
        up = np.array(up)
        prob = np.prod(np.where(up, p_e, 1 - p_e))
        new = alg.update(PDTDState(w, mu), sample, heard(graph, alg, PDTDState(w, mu), up[None]), 0.5)
        mean_w, mean_mu = mean_w + prob * new.w, mean_mu + prob * new.mu
    fixed = alg.update(PDTDState(w, mu), sample, MatrixInbox(graph.laplacian(p_e), alg.sends(PDTDState(w, mu))), 0.5)
    assert_allclose(mean_w, fixed.w, atol=1e-12)
    assert_allclose(mean_mu, fixed.mu, atol=1e-12)


def test_metropolis_weights_are_symmetric_doubly_stochastic_on_every_graph():
    """W(k) = I - L_W(k) has nonnegative entries and unit row sums for every pattern of links up."""
    graph = topologies.ring_with_chords(6, 2)
    rng = np.random.default_rng(3)
    up = rng.uniform(size=(50, graph.n_edges)) < 0.5
    for u in up:
        W = np.eye(6) - metropolis_laplacian(graph, u)
        assert np.all(W >= -1e-15)
        assert_allclose(W.sum(axis=1), 1.0, atol=1e-14)
        assert_allclose(W, W.T, atol=0)


def chain_problem(n_agents: int = 3):
    """A 4-state on-policy chain, 2 features, rewards that differ across agents."""
    P = np.array([[0.1, 0.6, 0.2, 0.1], [0.3, 0.1, 0.5, 0.1], [0.2, 0.2, 0.2, 0.4], [0.5, 0.1, 0.1, 0.3]])
    R = np.array([[1.0, 0.0, 2.0, 0.5], [0.0, 1.0, 0.5, 2.0], [2.0, 2.0, 0.0, 0.0]])[:n_agents]
    Phi = np.array([[1.0, 0.0], [0.7, 0.3], [0.3, 0.7], [0.0, 1.0]])
    return make_problem(P, R, Phi, 0.7)


@pytest.mark.parametrize("name, alpha0", [("td0", 1.0), ("gtd2", 3.0), ("tdc", 3.0)])
def test_centralised_learners_reach_the_exact_fixed_point(name, alpha0):
    """On a small on-policy chain the tail-averaged iterate of 4 seeds lies within 1 % of w* (max-norm).

    Tolerance: with alpha_k = alpha0 / sqrt(k + 10) over 200,000 steps the measured worst error over 8 seeds
    (base seeds 0 and 1) is 0.12 % for each method; 1 % is eight times that, and well below the 11.6 %
    distance from w* to the nearest agent's own fixed point A^-1 b_i, so a wrong fixed point fails.
    """
    p = chain_problem()
    net = random_edges(topologies.ring(3), 1.0)
    alg = make_algorithm(name, alpha0=alpha0, beta=10.0)
    r = run(p, net, alg, Sampling(), RunSettings(iterations=200_000, seeds=4, checkpoints=5, backend="numba"))
    assert r.w_tail.shape == (4, 1, 2)
    assert exact.relative_error(r.w_tail, r.w_star).max() < 0.01
    own = np.linalg.solve(exact.Moments(p).A, exact.Moments(p).b.T).T
    assert exact.relative_error(own, r.w_star).min() > 0.1


def test_dgtd_with_one_agent_is_gtd2_on_the_same_samples():
    """With N = 1 the Laplacian terms vanish, v and mu stay 0, and Algorithm 1 is GTD2 with eta = 1 (its
    theta is GTD2's auxiliary vector): identical iterates on the same samples while the projection does
    not bind. The known difference is the projection: with a small box DGTD's update stays inside it, GTD2 does not
    (a run refuses a box that excludes the saddle point: `tests/algorithms/test_boxes.py`)."""
    p = chain_problem(n_agents=1)
    net = random_edges(topologies.path(1), 1.0)
    st = RunSettings(iterations=5000, seeds=3, checkpoints=4, backend="numpy")
    d = run(p, net, DGTD(alpha0=1.0, beta=10.0, boxes=(1e6, 1e6, 1e6, 1e6)), Sampling(), st)
    g = run(p, net, make_algorithm("gtd2", alpha0=1.0, beta=10.0, eta=1.0), Sampling(), st)
    assert_allclose(d.w_last, g.w_last, rtol=1e-12, atol=1e-12)
    assert_allclose(d.final_state["theta"], g.final_state["theta"], rtol=1e-12, atol=1e-12)
    assert_allclose(d.w_avg, g.w_avg, rtol=1e-12, atol=1e-12)
    c = 0.5 * float(np.abs(g.w_last).max())
    boxed = DGTD(alpha0=1.0, beta=10.0, boxes=(1e6, 1e6, 1e6, c))
    with pytest.raises(DgtdInputError, match="excludes the saddle point"):
        run(p, net, boxed, Sampling(), st)
    from dgtd.algorithms.dgtd import DGTDState

    state = DGTDState(*(d.final_state[f] for f in DGTDState._fields))._replace(w=g.w_last.copy())
    B, q = g.w_last.shape[0], g.w_last.shape[-1]
    sample = Sample(np.ones((B, 1, q)), np.zeros((B, 1, q)), np.ones((B, 1)), np.ones((B, 1)), p.gamma)
    after = boxed.update(state, sample, heard(net.base, boxed, state), 0.0)  # step 0: projection only
    assert np.abs(after.w).max() <= c + 1e-12 < np.abs(g.w_last).max()


def test_registry_and_messages():
    """Every algorithm sends what it declares, each message an array of its state's shape; DGTD sends w and v + mu
    (two vectors where Algorithm 1's text sends three), the centralised and local learners nothing."""
    for name, cls in ALGORITHMS.items():
        alg = make_algorithm(name)
        state = alg.init(2, 3, 4)
        sent = alg.sends(state)
        assert tuple(sent) == cls.messages, name
        assert all(x.shape == (2, 3, 4) for x in sent.values()), name
    assert ALGORITHMS["dgtd"].messages == ("w", "vmu")
    assert all(not ALGORITHMS[n].messages for n in ("gtd2", "tdc", "td0", "local"))
    with pytest.raises(DgtdInputError, match="unknown algorithm"):
        make_algorithm("td1")
    with pytest.raises(DgtdInputError, match="no setting kappa"):
        make_algorithm("td0", kappa=1.0)
    with pytest.raises(DgtdInputError, match="eta"):
        make_algorithm("gtd2", eta=0.0)
    with pytest.raises(DgtdInputError, match="alpha0"):
        make_algorithm("pd-td", alpha0=-1.0)
    assert replace(make_algorithm("tdc"), alpha0=2.0).alpha0 == 2.0


@pytest.mark.parametrize("cls", [TDTracking, TDCTracking])
def test_tracking_keeps_the_tracker_sum_equal_to_the_direction_sum(cls):
    """W(k) is doubly stochastic, so after every step sum_i z_i(k) = sum_i g_i(k) exactly (to rounding), whatever
    links are up: the tracker follows the network-average direction (Wang et al. 2020), TD's or TDC's."""
    graph = topologies.ring_with_chords(6, 2)
    rng = np.random.default_rng(4)
    alg = cls(alpha0=0.5)
    state = alg.init(2, 6, 3)
    for _ in range(20):
        sample = Sample(
            rng.uniform(size=(2, 6, 3)),
            rng.uniform(size=(2, 6, 3)),
            rng.uniform(size=(2, 6)),
            rng.uniform(0.5, 1.5, size=(2, 6)),
            0.9,
        )
        state = alg.update(state, sample, heard(graph, alg, state, rng.uniform(size=(2, graph.n_edges)) < 0.5), 0.3)
        assert_allclose(state.z.sum(axis=1), state.g.sum(axis=1), atol=1e-12)


def test_td_tracking_has_consensus_on_w_star_as_its_exact_fixed_point():
    """At w_i = w*, z_i = 0 and g_i = b_i - A w* (the mean local direction there), the expected step changes
    nothing: E[z'] = W 0 + E[g_i(w*)] - g_i = 0 and E[w'] = W (1 w*) + alpha 0 = 1 w*. Away from it, the step is
    not zero. Exact expectations over every outcome of a 5-state MDP."""
    p = small_mdp(False, n_agents=4)
    m = exact.Moments(p)
    graph = topologies.from_edges(4, [(0, 1), (1, 2), (2, 3), (0, 2)])
    w_star = exact.w_star(m)
    w = np.broadcast_to(w_star, (1, 4, 3)).copy()
    g = (m.b - w_star @ m.A.T)[None]  # (1, N, q): b_i - A w*, nonzero per agent, zero on average
    assert np.abs(g).max() > 1e-3
    e = expected(p, TDTracking(), TrackingState(g=g, w=w, z=np.zeros_like(w)), graph)
    assert_allclose(e.w, w, atol=1e-12)
    assert_allclose(e.z, 0.0, atol=1e-12)
    moved = expected(p, TDTracking(), TrackingState(g=g, w=w + 0.1, z=np.zeros_like(w)), graph)
    assert np.abs(moved.w - (w + 0.1)).max() > 1e-3


@pytest.mark.parametrize("backend", [pytest.param("numpy", marks=pytest.mark.slow), "numba"])  # the reference: slow
def test_td_tracking_reaches_w_star_on_random_links(backend):
    """On the 4-state chain with 3 agents on a ring whose links are up with probability 0.7, the tail-averaged
    iterates of 4 seeds lie within 2 % of w* (max-norm), every agent.

    Tolerance: alpha_k = 1 / sqrt(k + 10) over 100,000 steps gives a measured worst error of 0.5 % over 8 seeds
    (base seeds 0 and 1); 2 % is several times that and far below the 11.6 % distance from w* to the nearest
    agent's own fixed point, so tracking the wrong average fails."""
    p = chain_problem()
    net = random_edges(topologies.ring(3), 0.7)
    r = run(
        p,
        net,
        TDTracking(alpha0=1.0, beta=10.0),
        Sampling(),
        RunSettings(iterations=100_000, seeds=4, checkpoints=5, backend=backend),
    )
    assert r.w_tail.shape == (4, 3, 2)
    assert exact.relative_error(r.w_tail, r.w_star).max() < 0.02
    assert r.info["counts"]["messages"][-1].min() > 0  # two vectors per link up, both ways


def test_an_algorithm_without_a_compiled_step_runs_on_the_reference_with_a_notice():
    """An algorithm that writes ``update`` alone (not the one definition of `dgtd.algorithms.base`): the run loop says
    in one line that it has no compiled step, and runs it on the reference backend (the same numbers as --backend
    numpy)."""
    from dataclasses import dataclass
    from typing import ClassVar

    @dataclass(frozen=True)
    class HalfStepTD0(TD0):
        name: ClassVar[str] = "half-step-td0"

        def update(self, state, sample, inbox, alpha):
            return super().update(state, sample, inbox, 0.5 * alpha)

    p = chain_problem()
    net = random_edges(topologies.ring(3), 1.0)
    settings = dict(iterations=500, seeds=2, checkpoints=2)
    with pytest.warns(UserWarning, match="writes update alone") as notices:
        compiled = run(p, net, HalfStepTD0(), Sampling(), RunSettings(**settings, backend="numba"))
    assert len(notices) == 1 and "half-step-td0" in str(notices[0].message)
    reference = run(p, net, HalfStepTD0(), Sampling(), RunSettings(**settings, backend="numpy"))
    assert_allclose(compiled.w_last, reference.w_last, rtol=0, atol=0)
    assert not np.allclose(compiled.w_last, run(p, net, TD0(), Sampling(), RunSettings(**settings)).w_last)


def test_tdc_runs_on_two_timescales_by_default():
    """Sutton et al. (2009), section 5: alpha_k / beta_k -> 0. With harmonic value steps alpha_k = alpha0 / (k + beta),
    beta_k = eta alpha0 (alpha_k / alpha0)^(2/3) ~ k^(-2/3): the ratio falls like k^(-1/3); GTD2 keeps a constant
    one."""
    tdc, gtd2 = make_algorithm("tdc", schedule="harmonic", alpha0=1.0), make_algorithm("gtd2", schedule="harmonic")
    k = np.array([1e2, 1e4, 1e6])
    alpha = 1.0 / (k + 1.0)
    ratio = alpha / np.array([tdc.aux_step(a) for a in alpha])
    assert_allclose(ratio, (k + 1.0) ** (-1 / 3), rtol=1e-12)
    assert gtd2.timescale == 1.0 and gtd2.aux_step(0.25) == 0.25 * gtd2.eta
    with pytest.raises(DgtdInputError, match="timescale must lie in"):
        make_algorithm("tdc", timescale=1.5)
