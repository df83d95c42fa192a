"""The compiled backend's vector primitives against plain Python, bit for bit (every algorithm's compiled step against
its ``update``: tests/backends/test_compiled_steps.py)."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit
from numpy.testing import assert_allclose

from dgtd.backends.compiled.simd import LANES, UNROLLED_NEIGHBOURS, dot, neighbour_sums


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
    neighbour_sums(Z, (0, b), i, J, at, count, out, (0, at))


@pytest.mark.parametrize("count", [0, 1, 3, UNROLLED_NEIGHBOURS, UNROLLED_NEIGHBOURS + 1, 12])
@pytest.mark.parametrize("K", [1, LANES - 1, 2 * LANES + 3, 64])
def test_neighbour_sums_are_the_laplacian_rows_in_order(count, K):
    """out[at] = count Z[b, i] - Z[b, J[at, 0]] - ... in this order, for straight-line counts and the general loop;
    the other scratch rows stay untouched."""
    rng = np.random.default_rng(count * 100 + K)
    Z = rng.standard_normal((1, 2, 14, K))  # (messages, seeds, agents, K), as the driver stacks them
    J = np.zeros((3, 12), np.int64)
    J[1] = rng.permutation(np.delete(np.arange(14), 4))[:12]
    out = np.full((1, 3, K + 2), 7.0)
    sums(Z, 1, 4, J, count, out, 1)
    want = count * Z[0, 1, 4]
    for n in range(count):
        want = want - Z[0, 1, J[1, n]]
    assert np.array_equal(out[0, 1, :K], want)
    assert np.all(out[0, 1, K:] == 7.0) and np.all(out[0, [0, 2]] == 7.0)  # nothing past the row, nor in other rows
