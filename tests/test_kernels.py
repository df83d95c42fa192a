"""Compiled helpers of the numba backend against plain Python: the hand-vectorised dot products, neighbour
sums and updates."""

import numpy as np
import pytest
from numba import njit

from dgtd.backends.numba_simd import UNROLLED_NEIGHBOURS, _dense_updates, _dots3, _laplacian_rows


@njit
def dots3(Phi, s, sn, theta, Z, b, i, q):
    return _dots3(Phi, s, sn, theta, Z, b, i, q)


def lane_order_dot(x, y):
    """The documented order: lane l sums products l, l + 4, ... in turn; (l0 + l1) + (l2 + l3); then the rest."""
    q = len(x)
    q4 = q - q % 4
    lanes = [0.0] * 4
    for f in range(q4):
        lanes[f % 4] = lanes[f % 4] + float(x[f]) * float(y[f])
    total = (lanes[0] + lanes[1]) + (lanes[2] + lanes[3])
    for f in range(q4, q):
        total = total + float(x[f]) * float(y[f])
    return total


@pytest.mark.parametrize("q", [1, 3, 4, 5, 8, 63, 64, 65, 400])
def test_dots3_sums_in_its_fixed_order(q):
    """Bit for bit the documented summation order (so every process gets the same bits), and the dot product."""
    rng = np.random.default_rng(q)
    Phi = rng.standard_normal((6, q))
    theta = rng.standard_normal((2, 3, q))
    Z = rng.standard_normal((2, 3, 2 * q))  # packed rows (w, v + mu): only the first q entries are w
    got = dots3(Phi, 4, 1, theta, Z, 1, 2, q)
    w = Z[1, 2, :q]
    assert got == (lane_order_dot(Phi[4], theta[1, 2]), lane_order_dot(Phi[4], w), lane_order_dot(Phi[1], w))
    np.testing.assert_allclose(got, (Phi[4] @ theta[1, 2], Phi[4] @ w, Phi[1] @ w), rtol=1e-12, atol=1e-12)


@njit
def laplacian_rows(Z, b, i, js, count, L, l):
    _laplacian_rows(Z, b, i, js, count, L, l)


@pytest.mark.parametrize("m", [2, 15, 16, 17, 128, 130])
@pytest.mark.parametrize("count", [0, 1, 3, UNROLLED_NEIGHBOURS, UNROLLED_NEIGHBOURS + 1, 12])
def test_laplacian_rows_in_its_fixed_order(m, count):
    """count Z_i - Z_j1 - Z_j2 - ..., element by element in that order: bit for bit, whatever the row length, for
    counts with straight-line code and counts past them (the general loop)."""
    rng = np.random.default_rng(m + 100 * count)
    Z = rng.standard_normal((2, 16, m))
    js = np.full(16, 99, dtype=np.int64)  # entries past count are never read (99 is out of range)
    js[:count] = rng.choice(np.delete(np.arange(16), 3), size=count, replace=False)
    L = np.full((3, m), np.nan)
    laplacian_rows(Z, 1, 3, js, count, L, 2)
    expected = count * Z[1, 3]
    for j in js[:count]:
        expected = expected - Z[1, j]
    assert np.array_equal(L[2], expected)
    assert np.isnan(L[[0, 1]]).all()  # the other rows are untouched


@njit
def dense_updates(Z, Zo, b, i, V, MU, theta, sum_all, sum_tail, in_tail, L, l, Phi, s, sn, alpha, rho, kappa, gamma,
                  rt, c_theta, b_th, b_v, b_mu, b_w):
    _dense_updates(Z, Zo, b, i, V, MU, theta, sum_all, sum_tail, in_tail, L, l, Phi, s, sn, alpha, rho, kappa, gamma,
                   rt, c_theta, b_th, b_v, b_mu, b_w)


def clip(x, bound):
    return -bound if x < -bound else (bound if x > bound else x)


def same(x, y):
    """Equal bit for bit up to NaN payloads: NaN for NaN, and zeros of the same sign."""
    return (np.isnan(x) and np.isnan(y)) or (x == y and np.signbit(x) == np.signbit(y))


SMALL_BOXES = (1.2, 0.8, 0.9, 1.1)  # theta, v, mu, w: some updates land outside and are clipped
ODD_BOXES = (0.0, np.inf, np.nan, 0.0)  # clipped to signed zeros, never clipped, and a NaN bound (no clipping)


@pytest.mark.parametrize("q", [1, 4, 7, 64])
@pytest.mark.parametrize("in_tail", [False, True])
@pytest.mark.parametrize("in_place", [False, True])
@pytest.mark.parametrize("boxes", [SMALL_BOXES, ODD_BOXES])
def test_dense_updates_are_algorithm_1_lines_7_to_9(q, in_tail, in_place, boxes):
    """Bit for bit the element-wise updates of Algorithm 1 lines 7-9 as plain Python writes them, with the
    projections of line 9 active, in place (Zo is Z) or into another buffer; with odd boxes (zero, infinite,
    NaN) and a NaN in v and mu, the projections keep `_clip`'s signed zeros and NaNs."""
    rng = np.random.default_rng(q)
    B, N, S = 2, 3, 5
    Z, V, MU, theta = (rng.standard_normal((B, N, k)) for k in (2 * q, q, q, q))
    if boxes is ODD_BOXES:
        V[1, 2, q // 2] = MU[1, 2, 0] = np.nan
    sum_all, sum_tail = rng.standard_normal((B, N, q)), rng.standard_normal((B, N, q))
    L, Phi = rng.standard_normal((2, 2 * q)), rng.standard_normal((S, q))
    Zo = Z if in_place else np.full_like(Z, np.nan)
    b, i, l, s, sn = 1, 2, 1, 3, 0
    alpha, rho, kappa, gamma, rt, c_theta = 0.3, 0.1, 1.5, 0.9, 0.7, -0.4
    old = [x.copy() for x in (Z, V, MU, theta, sum_all, sum_tail)]
    w0, v0, mu0, th0, sa0, st0 = (x[b, i] for x in old)
    dense_updates(Z, Zo, b, i, V, MU, theta, sum_all, sum_tail, in_tail, L, l, Phi, s, sn, alpha, rho, kappa, gamma,
                  rt, c_theta, *boxes)
    for f in range(q):
        w, lw, lvm = w0[f], L[l, f], L[l, q + f]
        v_new = clip(v0[f] - alpha * (v0[f] - lw), boxes[1])
        mu_new = clip(mu0[f] - alpha * (-lw + rho * mu0[f]), boxes[2])
        g_w = rt * (Phi[s, f] - gamma * Phi[sn, f]) - lvm - kappa * lw - rho * w
        assert same(V[b, i, f], v_new) and same(MU[b, i, f], mu_new)
        assert same(Zo[b, i, f], clip(w + alpha * g_w, boxes[3])) and same(Zo[b, i, q + f], v_new + mu_new)
        assert same(theta[b, i, f], clip(th0[f] - alpha * (Phi[s, f] * c_theta), boxes[0]))
        assert same(sum_all[b, i, f], sa0[f] + w)
        assert same(sum_tail[b, i, f], st0[f] + w if in_tail else st0[f])
    others = np.ones((B, N), bool)
    others[b, i] = False
    for new, before in zip((V, MU, theta, sum_all, sum_tail), old[1:]):
        assert np.array_equal(new[others], before[others])  # other agents and seeds are untouched
