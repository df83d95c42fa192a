"""Compiled helpers of the numba backend against plain Python: the hand-vectorised dot products and neighbour sums."""

import numpy as np
import pytest
from numba import njit

from dgtd.backends.numba_simd import _dots3, _laplacian_rows


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
@pytest.mark.parametrize("count", [0, 1, 3])
def test_laplacian_rows_in_its_fixed_order(m, count):
    """count Z_i - Z_j1 - Z_j2 - ..., element by element in that order: bit for bit, whatever the row length."""
    rng = np.random.default_rng(m + 100 * count)
    Z = rng.standard_normal((2, 5, m))
    js = np.array([4, 0, 2, 99][:count] + [99] * (4 - count), dtype=np.int64)  # entries past count are never read
    L = np.full((3, m), np.nan)
    laplacian_rows(Z, 1, 3, js, count, L, 2)
    expected = count * Z[1, 3]
    for j in js[:count]:
        expected = expected - Z[1, j]
    assert np.array_equal(L[2], expected)
    assert np.isnan(L[[0, 1]]).all()  # the other rows are untouched
