"""Compiled helpers of the numba backend against plain Python: the blocked rows, the hand-vectorised dot products
and the fused agent pass of Algorithm 1 lines 7-9, bit for bit."""

import numpy as np
import pytest
from numba import njit

from dgtd.backends.compiled.simd import (MU, SHARED, STATE, SUM_W, THETA, UNROLLED_NEIGHBOURS, UNROLLED_WITHOUT_TD, V,
                                      VMU, W, _agent_pass, _dots3, blocks, from_blocks, shared_index, state_index,
                                      to_blocks)


@njit
def indices(f, k):
    return state_index(f, k), shared_index(f, k % 2)


@pytest.mark.parametrize("q", [1, 3, 4, 5, 9])
def test_blocked_rows_round_trip_and_index(q):
    """to_blocks puts feature f of variable k where state_index / shared_index say, pads with zeros, and
    from_blocks takes it back out."""
    rng = np.random.default_rng(q)
    state = [rng.standard_normal((2, 3, q)) for _ in range(4)]
    shared = [rng.standard_normal((2, 3, q)) for _ in range(2)]
    S, Z = to_blocks(state, q), to_blocks(shared, q)
    assert S.shape == (2, 3, STATE * blocks(q)) and Z.shape == (2, 3, SHARED * blocks(q))
    for f in range(q):
        for k in range(4):
            si, zi = indices(f, k)
            assert S[1, 2, si] == state[k][1, 2, f]
            assert Z[1, 2, zi] == shared[k % 2][1, 2, f]
    assert np.count_nonzero(S[0, 0]) == 4 * q  # the padding of a partial last block is zero
    for k, x in enumerate(state):
        assert np.array_equal(from_blocks(S, k, 4, q), x)
    for k, x in enumerate(shared):
        assert np.array_equal(from_blocks(Z, k, 2, q), x)


@njit
def dots3(Phi, s, sn, S, Z, b, i, q):
    return _dots3(Phi, s, sn, S, Z, b, i, q)


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


def blocked(rng, q, B=2, N=3):
    """Random natural (B, N, q) arrays of the state and shared variables and their blocked rows."""
    state = [rng.standard_normal((B, N, q)) for _ in range(4)]  # theta, v, mu, running sum of w
    shared = [rng.standard_normal((B, N, q)), None]
    shared[1] = state[V] + state[MU]
    return state, shared, to_blocks(state, q), to_blocks(shared, q)


@pytest.mark.parametrize("q", [1, 3, 4, 5, 8, 63, 64, 65, 400])
def test_dots3_sums_in_its_fixed_order(q):
    """Bit for bit the documented summation order (so every process gets the same bits), and the dot product."""
    rng = np.random.default_rng(q)
    Phi = rng.standard_normal((6, q))
    state, shared, S, Z = blocked(rng, q)
    got = dots3(Phi, 4, 1, S, Z, 1, 2, q)
    theta, w = state[THETA][1, 2], shared[W][1, 2]
    assert got == (lane_order_dot(Phi[4], theta), lane_order_dot(Phi[4], w), lane_order_dot(Phi[1], w))
    np.testing.assert_allclose(got, (Phi[4] @ theta, Phi[4] @ w, Phi[1] @ w), rtol=1e-12, atol=1e-12)


@njit
def agent_pass(Zi, Zo, S, b, i, js, count, Phi, s, sn, s_next, sn_next, q, alpha, rho, kappa, gamma, rt, c_theta,
               b_th, b_v, b_mu, b_w):
    return _agent_pass(Zi, Zo, S, b, i, js, count, Phi, s, sn, s_next, sn_next, q, alpha, rho, kappa, gamma, rt,
                       c_theta, b_th, b_v, b_mu, b_w)


@njit
def agent_pass_alone(Zi, Zo, S, b, i, js, count, Phi, s, sn, q, alpha, rho, kappa, gamma, rt, c_theta, b_th, b_v, b_mu,
                     b_w):
    return _agent_pass(Zi, Zo, S, b, i, js, count, Phi, s, sn, None, None, q, alpha, rho, kappa, gamma, rt, c_theta,
                       b_th, b_v, b_mu, b_w)


@njit
def agent_pass_without_td(Zi, Zo, S, b, i, js, count, q, alpha, rho, kappa, gamma, rt, c_theta, b_th, b_v, b_mu, b_w):
    return _agent_pass(Zi, Zo, S, b, i, js, count, None, 0, 0, None, None, q, alpha, rho, kappa, gamma, rt, c_theta,
                       b_th, b_v, b_mu, b_w)


def clip(x, bound):
    return -bound if x < -bound else (bound if x > bound else x)


def same(x, y):
    """Equal bit for bit up to NaN payloads: NaN for NaN, and zeros of the same sign."""
    return (np.isnan(x) and np.isnan(y)) or (x == y and np.signbit(x) == np.signbit(y))


SMALL_BOXES = (1.2, 0.8, 0.9, 1.1)  # theta, v, mu, w: some updates land outside and are clipped
ODD_BOXES = (0.0, np.inf, np.nan, 0.0)  # clipped to signed zeros, never clipped, and a NaN bound (no clipping)
COUNTS = [0, 1, 3, UNROLLED_NEIGHBOURS, UNROLLED_NEIGHBOURS + 1, 12]  # straight-line code, and the general loop


def expected_pass(state, shared, b, i, js, Phi, s, sn, alpha, rho, kappa, gamma, rt, c_theta, boxes, td=True):
    """Algorithm 1 lines 7-9 for agent i as plain Python writes it, feature by feature: the new theta, v, mu,
    running sum, w and v + mu."""
    q = state[0].shape[2]
    out = {k: np.empty(q) for k in ("theta", "v", "mu", "sum", "w", "vmu")}
    for f in range(q):
        w, z = shared[W][b, i, f], shared[VMU][b, i, f]
        lw, lvm = len(js) * w, len(js) * z
        for j in js:
            lw, lvm = lw - shared[W][b, j, f], lvm - shared[VMU][b, j, f]
        v0, mu0, th0 = state[V][b, i, f], state[MU][b, i, f], state[THETA][b, i, f]
        out["sum"][f] = state[SUM_W][b, i, f] + w
        out["v"][f] = clip(v0 - alpha * (v0 - lw), boxes[1])
        out["mu"][f] = clip(mu0 - alpha * (-lw + rho * mu0), boxes[2])
        out["vmu"][f] = out["v"][f] + out["mu"][f]
        if td:
            g_w = rt * (Phi[s, f] - gamma * Phi[sn, f]) - lvm - kappa * lw - rho * w
            out["theta"][f] = clip(th0 - alpha * (Phi[s, f] * c_theta), boxes[0])
        else:
            g_w = -lvm - kappa * lw - rho * w
            out["theta"][f] = th0
        out["w"][f] = clip(w + alpha * g_w, boxes[3])
    return out


def check_pass(got, S, Zo, S_before, Zo_before, b, i, q, want):
    sv = from_blocks(S, 0, 4, q), from_blocks(S, 1, 4, q), from_blocks(S, 2, 4, q), from_blocks(S, 3, 4, q)
    for f in range(q):
        assert same(sv[THETA][b, i, f], want["theta"][f]) and same(sv[V][b, i, f], want["v"][f])
        assert same(sv[MU][b, i, f], want["mu"][f]) and same(sv[SUM_W][b, i, f], want["sum"][f])
        assert same(from_blocks(Zo, W, 2, q)[b, i, f], want["w"][f])
        assert same(from_blocks(Zo, VMU, 2, q)[b, i, f], want["vmu"][f])
    others = np.ones(S.shape[:2], bool)
    others[b, i] = False
    assert np.array_equal(S[others], S_before[others], equal_nan=True)  # other agents and seeds untouched
    assert np.array_equal(Zo[others], Zo_before[others], equal_nan=True)


@pytest.mark.parametrize("q", [1, 4, 7, 64])
@pytest.mark.parametrize("count", COUNTS)
@pytest.mark.parametrize("has_next", [False, True])
@pytest.mark.parametrize("boxes", [SMALL_BOXES, ODD_BOXES])
def test_agent_pass_is_algorithm_1_lines_7_to_9(q, count, has_next, boxes):
    """Bit for bit the element-wise updates of Algorithm 1 lines 7-9 as plain Python writes them, neighbour sums
    included, with the projections of line 9 active, for any number of neighbours; with odd boxes (zero,
    infinite, NaN) and a NaN in v and mu, the projections keep `_clip`'s signed zeros and NaNs. Given the next
    step's states, the pass returns the dot products of the new theta and w, in `_dots3`'s order; zeros without."""
    rng = np.random.default_rng(q + 100 * count)
    B, N, n_states = 2, 16, 5
    state, shared, S, Zi = blocked(rng, q, B, N)
    if boxes is ODD_BOXES:
        state[V][1, 2, q // 2] = state[MU][1, 2, 0] = np.nan
        S = to_blocks(state, q)
    Phi = rng.standard_normal((n_states, q))
    js = np.full(16, 99, dtype=np.int64)  # entries past count are never read (99 is out of range)
    js[:count] = rng.choice(np.delete(np.arange(N), 2), size=count, replace=False)
    Zo = np.full_like(Zi, np.nan)
    S_before, Zo_before = S.copy(), Zo.copy()
    b, i, s, sn, s_next, sn_next = 1, 2, 3, 0, 4, 1
    alpha, rho, kappa, gamma, rt, c_theta = 0.3, 0.1, 1.5, 0.9, 0.7, -0.4
    scalars = (q, alpha, rho, kappa, gamma, rt, c_theta, *boxes)
    if has_next:
        got = agent_pass(Zi, Zo, S, b, i, js, count, Phi, s, sn, s_next, sn_next, *scalars)
    else:
        got = agent_pass_alone(Zi, Zo, S, b, i, js, count, Phi, s, sn, *scalars)
    want = expected_pass(state, shared, b, i, js[:count], Phi, s, sn, alpha, rho, kappa, gamma, rt, c_theta, boxes)
    check_pass(got, S, Zo, S_before, Zo_before, b, i, q, want)
    if has_next:
        expect = (lane_order_dot(Phi[s_next], want["theta"]), lane_order_dot(Phi[s_next], want["w"]),
                  lane_order_dot(Phi[sn_next], want["w"]))
        assert all(same(x, y) for x, y in zip(got, expect))
    else:
        assert got == (0.0, 0.0, 0.0)


@pytest.mark.parametrize("q", [3, 64])
@pytest.mark.parametrize("count", [2, UNROLLED_WITHOUT_TD + 1, UNROLLED_NEIGHBOURS + 1])
def test_agent_pass_without_td_terms(q, count):
    """With no Phi (the sparse kernels add the TD terms themselves), the pass is lines 7-9 with phi = phi' = 0:
    theta stays, w moves along the neighbour sums only."""
    rng = np.random.default_rng(q + count)
    B, N = 1, 16
    state, shared, S, Zi = blocked(rng, q, B, N)
    js = rng.choice(np.arange(1, N), size=count, replace=False).astype(np.int64)
    Zo = np.full_like(Zi, np.nan)
    S_before, Zo_before = S.copy(), Zo.copy()
    args = (0.3, 0.1, 1.5, 0.9, 0.7, -0.4)
    assert agent_pass_without_td(Zi, Zo, S, 0, 0, js, count, q, *args, *SMALL_BOXES) == (0.0, 0.0, 0.0)
    want = expected_pass(state, shared, 0, 0, js, None, 0, 0, *args, SMALL_BOXES, td=False)
    check_pass(None, S, Zo, S_before, Zo_before, 0, 0, q, want)
