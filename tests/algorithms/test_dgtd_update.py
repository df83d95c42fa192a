"""Algorithm 1's update against the Lagrangian, GTD2, and its invariances."""

import itertools

import numpy as np
import pytest
from numpy.testing import assert_allclose

from dgtd.algorithms import dgtd as alg
from dgtd.algorithms.dgtd import DGTD
from dgtd.channels import Arcs, Perfect
from dgtd.graphs import topologies
from dgtd.graphs.random import random_edges
from dgtd.problems import exact
from dgtd.problems.generators import random_mdp_problem, random_problem
from dgtd.samples import Sample


def expected_direction(problem, network, state, kappa, rho):
    """E[direction] summed exactly over s ~ d, (a, s') ~ beta P and all 2^|E| edge sets with their probabilities."""
    m = exact.Moments(problem)
    arcs = Arcs.of(network.base.edges, network.n_nodes)
    sent = DGTD().sends(state)
    S, A, _ = problem.P_sample.shape
    N = problem.n_agents
    total = [np.zeros_like(x) for x in state]
    for mask in itertools.product([0, 1], repeat=network.n_edges):
        mask = np.array(mask, dtype=bool)
        p_mask = np.prod(np.where(mask, network.p, 1 - network.p))
        if p_mask == 0:
            continue
        for s in range(S):
            for a in range(A):
                for sn in range(S):
                    weight = p_mask * m.d[s] * problem.P_sample[s, a, sn]
                    if weight == 0:
                        continue
                    phi = np.broadcast_to(problem.Phi[s], (1, N, problem.n_features))
                    phin = np.broadcast_to(problem.Phi[sn], (1, N, problem.n_features))
                    r = problem.R_sample[:, s, a][None, :]
                    ratio = np.full((1, N), problem.ratio[s, a])
                    g = alg.direction(
                        state,
                        Sample(phi, phin, r, ratio, problem.gamma),
                        Perfect().inbox(arcs, sent, mask[None]),
                        kappa,
                        rho,
                    )
                    for acc, x in zip(total, g):
                        acc += weight * x
    return total


@pytest.mark.parametrize("off_policy", [False, True])
@pytest.mark.parametrize("rho", [0.0, 0.3])
def test_expected_update_is_lagrangian_gradient(off_policy, rho, rng):
    if off_policy:
        p = random_mdp_problem(3, (2, 2, 1), 2, rng)
    else:
        p = random_problem(3, 3, 2, rng)
    net = random_edges(topologies.complete(3), [0.3, 0.6, 0.9])
    state = alg.DGTDState(*(rng.standard_normal((1, 3, 2)) for _ in range(4)))
    kappa = 0.7
    expected = expected_direction(p, net, state, kappa, rho)
    grad = exact.lagrangian_gradient(exact.Moments(p), net.mean_laplacian(), kappa, rho, *(x[0] for x in state))
    for e, g in zip(expected, grad):
        assert_allclose(e[0], g, rtol=1e-10, atol=1e-12)


def test_single_agent_is_gtd2(rng):
    # With N = 1 there are no edges: v and mu stay 0 and (theta, w) follow GTD2 (Sutton et al. 2009) with
    # theta the auxiliary weights: theta += a (delta - phi^T theta) phi;  w += a (phi - gamma phi') phi^T theta.
    p = random_problem(5, 1, 3, rng)
    arcs = Arcs.of(topologies.path(1).edges, 1)
    dgtd = DGTD(kappa=1.0, boxes=(1e9,) * 4)
    state = dgtd.init(1, 1, 3)
    th, w = np.zeros(3), np.zeros(3)
    for k in range(200):
        s, sn = rng.integers(5, size=2)
        r = p.R[0, s]
        a = 0.5 / np.sqrt(k + 1)
        phi, phin = p.Phi[s], p.Phi[sn]
        delta = r + p.gamma * phin @ w - phi @ w
        th, w = th + a * (delta - phi @ th) * phi, w + a * (phi - p.gamma * phin) * (phi @ th)
        sample = Sample(phi[None, None], phin[None, None], np.array([[r]]), np.ones((1, 1)), p.gamma)
        state = dgtd.update(state, sample, Perfect().inbox(arcs, dgtd.sends(state)), a)
    assert_allclose(state.theta[0, 0], th, rtol=1e-12)
    assert_allclose(state.w[0, 0], w, rtol=1e-12)
    assert np.all(state.v == 0) and np.all(state.mu == 0)


def test_kappa_term_reduces_disagreement(rng):
    # The kappa term adds -alpha kappa L w to w; on its own it is a consensus step, so from any disagreeing w
    # (with theta = v = mu = 0 and no TD signal) sum_i |w_i - mean w|^2 strictly falls for small alpha.
    N, q = 6, 3
    arcs = Arcs.of(topologies.ring(N).edges, N)
    w0 = rng.standard_normal((1, N, q))
    z = np.zeros_like(w0)
    state = alg.DGTDState(z, z, z, w0)
    phi = np.zeros((1, N, q))
    sample = Sample(phi, phi, np.zeros((1, N)), np.ones((1, N)), 0.9)
    inbox = Perfect().inbox(arcs, DGTD().sends(state))
    out0 = DGTD(kappa=0.0, boxes=(1e9,) * 4).update(state, sample, inbox, 0.1)
    out1 = DGTD(kappa=1.0, boxes=(1e9,) * 4).update(state, sample, inbox, 0.1)
    before = exact.consensus_error(w0)[0]
    assert_allclose(exact.consensus_error(out0.w)[0], before)  # kappa = 0: w does not move here
    assert exact.consensus_error(out1.w)[0] < 0.95 * before


def test_projection_keeps_iterates_in_boxes(rng):
    N, q = 3, 2
    arcs = Arcs.of(topologies.complete(N).edges, N)
    state = alg.DGTDState(*(100 * rng.standard_normal((2, N, q)) for _ in range(4)))
    phi = rng.standard_normal((2, N, q))
    boxes = (1.0, 2.0, 3.0, 4.0)
    sample = Sample(phi, phi, rng.random((2, N)), np.ones((2, N)), 0.9)
    out = DGTD(kappa=1.0, boxes=boxes).update(state, sample, Perfect().inbox(arcs, DGTD().sends(state)), 1.0)
    for x, b in zip(out, boxes):
        assert np.abs(x).max() <= b
