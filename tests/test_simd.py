"""The compiled backend's vector primitives against plain Python, bit for bit, and the DGTD agent step against
`DGTD.update`."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit
from numpy.testing import assert_allclose

from dgtd.algorithms.dgtd import DGTD
from dgtd.backends.compiled.kernels.dgtd import _agent_step
from dgtd.backends.compiled.simd import LANES, UNROLLED_NEIGHBOURS, dot, neighbour_sums
from dgtd.graphs import topologies
from dgtd.graphs.links import Links
from dgtd.graphs.random import LaplacianOperator
from dgtd.samples import Sample


@njit
def dot_rows(Phi, s, X, b, i, n):
    return dot(Phi, s, X, (b, i), n)


def documented_dot(x, y) -> float:
    """`dot`'s order: chunks of 2 LANES into a0 (first half) and a1 (second half), a last whole chunk of LANES into
    a0, then a0 + a1, its lanes added pairwise, then the remaining products in order."""
    n = len(x)
    p = [float(x[f]) * float(y[f]) for f in range(n)]
    a0, a1 = [0.0] * LANES, [0.0] * LANES
    n2, nv = n - n % (2 * LANES), n - n % LANES
    for f in range(0, n2, 2 * LANES):
        for lane in range(LANES):
            a0[lane] += p[f + lane]
            a1[lane] += p[f + LANES + lane]
    for f in range(n2, nv, LANES):
        for lane in range(LANES):
            a0[lane] += p[f + lane]
    terms = [a0[lane] + a1[lane] for lane in range(LANES)]
    while len(terms) > 1:
        terms = [terms[k] + terms[k + 1] for k in range(0, len(terms), 2)]
    total = terms[0]
    for f in range(nv, n):
        total += p[f]
    return total


@pytest.mark.parametrize("n", [0, 1, LANES - 1, LANES, LANES + 1, 2 * LANES, 3 * LANES + 3, 64, 67])
def test_dot_sums_in_its_documented_order(n):
    rng = np.random.default_rng(n)
    Phi, X = rng.standard_normal((5, n)), rng.standard_normal((2, 3, n)) * 10.0 ** rng.integers(-8, 8, size=n)
    got = dot_rows(Phi, 3, X, 1, 2, n)
    assert got == documented_dot(Phi[3], X[1, 2])  # the same bits, not merely close
    assert_allclose(got, Phi[3] @ X[1, 2], rtol=1e-12, atol=1e-12)


def test_dot_reads_only_the_first_n_elements_of_its_rows():
    Phi, X = np.ones((2, 8)), np.ones((1, 1, 8))
    X[0, 0, 5:] = np.nan
    assert dot_rows(Phi, 1, X, 0, 0, 5) == 5.0


@njit
def sums(Z, b, i, J, count, out, at):
    neighbour_sums(Z, b, i, J, count, out, at)


@pytest.mark.parametrize("count", [0, 1, 3, UNROLLED_NEIGHBOURS, UNROLLED_NEIGHBOURS + 1, 12])
@pytest.mark.parametrize("K", [1, LANES - 1, 2 * LANES + 3, 64])
def test_neighbour_sums_are_the_laplacian_rows_in_order(count, K):
    """out[at] = count Z[b, i] - Z[b, J[at, 0]] - ... in this order, for straight-line counts and the general loop;
    the other scratch rows stay untouched."""
    rng = np.random.default_rng(count * 100 + K)
    Z = rng.standard_normal((2, 14, K))
    J = np.zeros((3, 12), np.int64)
    J[1] = rng.permutation(np.delete(np.arange(14), 4))[:12]
    out = np.full((3, K + 2), 7.0)
    sums(Z, 1, 4, J, count, out, 1)
    want = count * Z[1, 4]
    for n in range(count):
        want = want - Z[1, J[1, n]]
    assert np.array_equal(out[1, :K], want)
    assert np.all(out[1, K:] == 7.0) and np.all(out[[0, 2]] == 7.0)  # nothing past the row, nor in other rows


@njit
def agent_step(state, shared, Lw, Lvmu, J, count, i, s, sn, r, ratio, alpha, q, Phi, params):
    theta, v, mu, sum_w = state
    w_in, vmu_in, w_out, vmu_out = shared
    e, ef = np.zeros(1, np.int64), np.zeros(1)
    continuing = np.ones(Phi.shape[0])  # a continuing task: every transition discounts by gamma
    _agent_step(theta, v, mu, sum_w, w_in, vmu_in, w_out, vmu_out, Lw, Lvmu, J, 0, count, 0, i, s, sn, r, ratio,
                alpha, q, Phi, False, e, e, ef, continuing, params)


@pytest.mark.parametrize("count", [0, 2, UNROLLED_NEIGHBOURS + 2])
@pytest.mark.parametrize("boxes", [(0.05, 0.02, 0.03, 0.04), (np.inf, 0.0, 0.0, 1e9)])
def test_agent_step_is_dgtd_update_for_one_agent(count, boxes):
    """Agent i's new theta, v, mu, w (and the running sum of w) from `_agent_step` are those of `DGTD.update` with
    the links from i to its count neighbours up, the projections active (small boxes) or pinning v and mu."""
    N, q, i = 12, 2 * LANES + 3, 5
    rng = np.random.default_rng(count)
    theta, v, mu, w = (0.1 * rng.standard_normal((1, N, q)) for _ in range(4))
    Phi = rng.standard_normal((4, q))
    s, sn, r, ratio, alpha, gamma, kappa, rho = 1, 3, 0.7, 1.3, 0.4, 0.9, 0.8, 0.2
    graph = topologies.complete(N)
    J = np.array([j for j in range(N) if j != i][:count], dtype=np.int64)
    up = np.array([[(a == i and b in J) or (b == i and a in J) for a, b in graph.edges]])
    sample = Sample(np.broadcast_to(Phi[s], (1, N, q)), np.broadcast_to(Phi[sn], (1, N, q)), np.full((1, N), r),
                    np.full((1, N), ratio), gamma)
    want = DGTD(kappa=kappa, rho=rho, boxes=boxes).update(DGTD().init(1, N, q)._make((theta, v, mu, w)), sample,
                                                          Links(LaplacianOperator(graph), up, 1), alpha)
    state = tuple(x.copy() for x in (theta, v, mu, np.full((1, N, q), 2.0)))
    shared = (w.copy(), v + mu, np.zeros((1, N, q)), np.zeros((1, N, q)))
    J_full = np.zeros((1, N), np.int64)
    J_full[0, :count] = J
    agent_step(state, shared, np.empty((1, q)), np.empty((1, q)), J_full, count, i, s, sn, r, ratio, alpha, q, Phi,
               (gamma, kappa, rho, *(float(b) for b in boxes)))
    for got, ref in zip(state[:3], want[:3]):
        assert_allclose(got[0, i], ref[0, i], rtol=1e-12, atol=1e-15)
    assert_allclose(shared[2][0, i], want.w[0, i], rtol=1e-12, atol=1e-15)
    assert_allclose(shared[3][0, i], want.v[0, i] + want.mu[0, i], rtol=1e-12, atol=1e-15)
    assert_allclose(state[3][0, i], 2.0 + w[0, i], rtol=0, atol=0)
