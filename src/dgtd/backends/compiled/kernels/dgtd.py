"""The compiled DGTD kernel: Algorithm 1 (section 7 of the paper) over a block of steps, `DGTD.update` line for line.

`_agent_step` is the update of one agent: its neighbour sums, the TD terms, then for each feature the lines of
`dgtd.algorithms.dgtd.direction` and `DGTD.update` in the same order and with the same names, as plain numba
expressions (LLVM vectorises the loop over features; no fastmath, so every process gets the same bits). The
generic vector primitives it calls, a dot product in a fixed lane order and the neighbour sums, are in
`dgtd.backends.compiled.simd`. Two differences from the reference, both exact in real arithmetic: (L(k) v)_i +
(L(k) mu)_i is one neighbour sum of v + mu, which the agents share instead of v and mu.

Samples are drawn inside the kernel from the seeds' PCG64 streams (`dgtd.backends.compiled.sampling`), the same
samples as the reference backend's. Two layouts: seeds spread over the cores (`_dgtd_by_seed`, small N, many
seeds) or agents (`_dgtd_by_agent`, large N, few seeds). The shared rows (w and v + mu, which neighbours read) are
double-buffered: every agent reads step k's while writing step k + 1's (the Jacobi form of Algorithm 1).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from dgtd.algorithms.dgtd import DGTDState
from dgtd.backends.compiled import kernel
from dgtd.backends.compiled.cache import load_quickly
from dgtd.backends.compiled.graph import per_run, storage_graph, storage_order
from dgtd.backends.compiled.primitives import continuing_flags, discount, readonly, rows_of
from dgtd.backends.compiled.sampling import _step_edges, _step_observations, _step_samples, sample_args
from dgtd.backends.compiled.simd import dot, neighbour_sums
from dgtd.samples import Draws

# Every variable is a C-contiguous array (B, N, q) of its own. With the variables side by side in one row, LLVM can
# prove the feature loop's stores and loads apart only at run time, and its check fails: the loop ran scalar.


@njit(cache=True, inline="always")
def _clip(x, bound):
    """Projection onto [-bound, bound] (Algorithm 1 line 9); NaN stays NaN. Testing the inner result rather than x
    twice lets LLVM emit one min and one max instruction (a compare and a blend per test otherwise)."""
    inner = bound if x > bound else x
    return -bound if inner < -bound else inner


@njit(cache=True, inline="always")
def _up_neighbours(J, at, up, row, indptr, nbr, eid, i):
    """The rows of agent i's neighbours whose links are up (row ``row`` of the step's edge mask) into J[at]; returns
    how many. Without a branch: links are up at random, and a branch would be mispredicted."""
    count = 0
    for p in range(indptr[i], indptr[i + 1]):
        J[at, count] = nbr[p]
        count += up[row, eid[p]]
    return count


@njit(cache=True, inline="always")
def _max_degree(indptr):
    d = 1
    for k in range(indptr.shape[0] - 1):
        d = max(d, indptr[k + 1] - indptr[k])
    return d


@njit(cache=True, inline="always")
def _csr_dot(ptr, idx, val, s, X, b, i):
    """phi(s)^T X[b, i] from the CSR rows of Phi (its few nonzero features, in increasing order)."""
    acc = 0.0
    for p in range(ptr[s], ptr[s + 1]):
        acc += val[p] * X[b, i, idx[p]]
    return acc


@njit(cache=True, inline="always")
def _csr_value(ptr, idx, val, s, f):
    """phi_f(s) from the CSR rows of Phi."""
    for p in range(ptr[s], ptr[s + 1]):
        if idx[p] == f:
            return val[p]
    return 0.0


@njit(cache=True, inline="always")
def _agent_step(theta, v, mu, sum_w, w_in, vmu_in, w_out, vmu_out, Lw, Lvmu, J, at, count, b, i, s, sn, r, ratio,
                alpha, q, Phi, sparse, ptr, idx, val, cont, params):
    """Algorithm 1 lines 7-9 for agent i of seed b at step k: `DGTD.update` for one agent. theta, v, mu and the
    running sum of w are updated in place; w_in and vmu_in (v + mu) are the shared rows at step k, w_out and
    vmu_out receive agent i's at step k + 1. J[at, :count] are its neighbours up at step k; rows ``at`` of Lw and
    Lvmu are the calling thread's scratch for its neighbour sums. q, the number of features, comes from the caller:
    computed here from a shape, LLVM cannot prove the feature loop's indices in range and leaves it scalar."""
    gamma, kappa, rho, b_theta, b_v, b_mu, b_w = params
    gamma = discount(gamma, cont, s, sn)  # gamma(s, s'): 0 into and out of an episodic task's terminal states
    neighbour_sums(w_in, b, i, J, count, Lw, at)  # (L(k) w)_i
    neighbour_sums(vmu_in, b, i, J, count, Lvmu, at)  # (L(k) v)_i + (L(k) mu)_i = (L(k) (v + mu))_i
    if sparse:
        phi_theta = _csr_dot(ptr, idx, val, s, theta, b, i)
        phi_w, phin_w = _csr_dot(ptr, idx, val, s, w_in, b, i), _csr_dot(ptr, idx, val, sn, w_in, b, i)
    else:
        phi_theta = dot(Phi, s, theta, (b, i), q)
        phi_w, phin_w = dot(Phi, s, w_in, (b, i), q), dot(Phi, sn, w_in, (b, i), q)
    # Line 7's theta direction is phi c_theta; line 8's TD part of w is ratio phi^T theta (phi - gamma phi')
    c_theta = phi_theta + ratio * (phi_w - gamma * phin_w - r)
    ratio_phi_theta = ratio * phi_theta
    for f in range(q):
        w = w_in[b, i, f]
        sum_w[b, i, f] += w  # the running sum of w_k behind the averaged iterates
        # Line 7, v: g_v = v - (L(k) w)_i
        v_new = _clip(v[b, i, f] - alpha * (v[b, i, f] - Lw[at, f]), b_v)
        # Line 8, mu: g_mu = -(L(k) w)_i + rho mu
        mu_new = _clip(mu[b, i, f] - alpha * (-Lw[at, f] + rho * mu[b, i, f]), b_mu)
        v[b, i, f] = v_new
        mu[b, i, f] = mu_new
        vmu_out[b, i, f] = v_new + mu_new
        # Line 8, w: g_w = ratio phi^T theta (phi - gamma phi') - (L v)_i - (L mu)_i - kappa (L w)_i - rho w
        phi, phi_next = (0.0, 0.0) if sparse else (Phi[s, f], Phi[sn, f])
        g_w = ratio_phi_theta * (phi - gamma * phi_next) - Lvmu[at, f] - kappa * Lw[at, f] - rho * w
        w_out[b, i, f] = _clip(w + alpha * g_w, b_w)
        # Line 7, theta: g_theta = phi (phi^T theta + ratio (phi^T w - gamma phi'^T w - r)) = phi c_theta
        theta[b, i, f] = _clip(theta[b, i, f] - alpha * (phi * c_theta), b_theta)
    if sparse:  # the loop took phi = phi' = 0; w and theta again where phi(s) or phi(s') is not zero
        for p in range(ptr[s], ptr[s + 1]):
            _sparse_td_feature(theta, w_in, w_out, Lw, Lvmu, at, b, i, idx[p], val[p],
                               _csr_value(ptr, idx, val, sn, idx[p]), alpha, gamma, kappa, rho, ratio_phi_theta,
                               c_theta, b_theta, b_w)
        for p in range(ptr[sn], ptr[sn + 1]):
            if _csr_value(ptr, idx, val, s, idx[p]) == 0.0:  # not done above
                _sparse_td_feature(theta, w_in, w_out, Lw, Lvmu, at, b, i, idx[p], 0.0, val[p], alpha, gamma, kappa,
                                   rho, ratio_phi_theta, c_theta, b_theta, b_w)


@njit(cache=True, inline="always")
def _sparse_td_feature(theta, w_in, w_out, Lw, Lvmu, at, b, i, f, phi, phi_next, alpha, gamma, kappa, rho,
                       ratio_phi_theta, c_theta, b_theta, b_w):
    """Feature f of w and theta, the lines of `_agent_step`'s loop, with phi_f(s) and phi_f(s') not both zero."""
    w = w_in[b, i, f]
    g_w = ratio_phi_theta * (phi - gamma * phi_next) - Lvmu[at, f] - kappa * Lw[at, f] - rho * w
    w_out[b, i, f] = _clip(w + alpha * g_w, b_w)
    theta[b, i, f] = _clip(theta[b, i, f] - alpha * (phi * c_theta), b_theta)


@njit(cache=True, parallel=True)
def _dgtd_by_seed(state, shared, q, alphas, sampler, model, ratio_tab, graph, params):
    """Seeds spread over the cores; within a seed, steps and agents run in order. Row i of the arrays holds agent
    agent_of[i] (`storage_order`). Returns the number of steps (odd: the last w is in the second buffer, w1)."""
    (fused, rng, markov, current, d_prob, d_alias, sa_prob, sa_alias, R_sample, sigma, noise, p_edge, s_blk, a_blk,
     sn_blk, r_blk, up_blk, n_up) = sampler
    indptr, nbr, eid, agent_of = graph
    Phi, sparse, ptr, idx, val, cont = model
    theta, v, mu, sum_w = state
    w0, vmu0, w1, vmu1 = shared  # step k reads (w0, vmu0) and writes (w1, vmu1) at even k, the other way at odd k
    B, N = theta.shape[0], theta.shape[1]
    T = alphas.shape[0]
    n_obs, E = current.shape[1], indptr[N] // 2
    degree = _max_degree(indptr)
    J, Lw, Lvmu = np.empty((B, degree), np.int64), np.empty((B, q)), np.empty((B, q))  # a row per seed, once per block
    for b in prange(B):
        s_t, a_t, sn_t = np.empty((1, n_obs), np.int64), np.empty((1, n_obs), np.int64), np.empty((1, n_obs), np.int64)
        r_t = np.empty((1, N))
        up_t = np.ones((1, E), np.bool_)
        for t in range(T):
            n_up[b] += _step_samples(b, 0, t, fused, rng, markov, current, d_prob, d_alias, sa_prob, sa_alias, R_sample,
                                     sigma, noise, p_edge, s_blk, a_blk, sn_blk, r_blk, up_blk, s_t, a_t, sn_t, r_t,
                                     up_t)
            w_in, vmu_in, w_out, vmu_out = (w0, vmu0, w1, vmu1) if t % 2 == 0 else (w1, vmu1, w0, vmu0)
            for i in range(N):
                count = _up_neighbours(J, b, up_t, 0, indptr, nbr, eid, i)
                o = agent_of[i] if n_obs == N else 0
                s, a, sn = s_t[0, o], a_t[0, o], sn_t[0, o]
                _agent_step(theta, v, mu, sum_w, w_in, vmu_in, w_out, vmu_out, Lw, Lvmu, J, b, count, b, i, s, sn,
                            r_t[0, agent_of[i]], ratio_tab[s, a], alphas[t], q, Phi, sparse, ptr, idx, val, cont, params)
    return T


@njit(cache=True, parallel=True)
def _dgtd_by_agent(state, shared, q, alphas, sampler, model, ratio_tab, graph, params, n_chunks):
    """Agents spread over the cores at every step. Samples are double-buffered too: while the agents update with
    step k's, the chunks also draw step k + 1's, each seed's state and reward streams in one chunk and its edge
    stream in another (a stream is sequential, but the streams are independent), so that no core waits while
    another samples. Returns the number of buffer swaps (odd: the last w is in w1)."""
    (fused, rng, markov, current, d_prob, d_alias, sa_prob, sa_alias, R_sample, sigma, noise, p_edge, s_blk, a_blk,
     sn_blk, r_blk, up_blk, n_up) = sampler
    indptr, nbr, eid, agent_of = graph
    Phi, sparse, ptr, idx, val, cont = model
    theta, v, mu, sum_w = state
    w0, vmu0, w1, vmu1 = shared  # step k reads (w0, vmu0) and writes (w1, vmu1) at even k, the other way at odd k
    B, N = theta.shape[0], theta.shape[1]
    T = alphas.shape[0]
    n_obs, E = current.shape[1], indptr[N] // 2
    degree = _max_degree(indptr)
    total = B * N
    s_t, a_t = np.empty((2 * B, n_obs), np.int64), np.empty((2 * B, n_obs), np.int64)
    sn_t = np.empty((2 * B, n_obs), np.int64)
    r_t = np.empty((2 * B, N))
    up_t = np.ones((2 * B, E), np.bool_)
    # each stream's words on cache lines of their own: two cores advance streams of the same seed at once
    words = np.zeros((B, 3, 16), np.uint64)
    words[:, :, :4] = rng
    for b in range(B if T > 0 else 0):  # step 0's samples (none for an empty block: the streams stay put)
        n_up[b] += _step_samples(b, b, 0, fused, words, markov, current, d_prob, d_alias, sa_prob, sa_alias, R_sample,
                                 sigma, noise, p_edge, s_blk, a_blk, sn_blk, r_blk, up_blk, s_t, a_t, sn_t, r_t, up_t)
    J, Lw, Lvmu = np.empty((n_chunks, degree), np.int64), np.empty((n_chunks, q)), np.empty((n_chunks, q))
    for t in range(T):
        w_in, vmu_in, w_out, vmu_out = (w0, vmu0, w1, vmu1) if t % 2 == 0 else (w1, vmu1, w0, vmu0)
        now, nxt = (t % 2) * B, ((t + 1) % 2) * B  # rows of this step's samples and the next step's
        for c in prange(n_chunks):
            hi = (c + 1) * total // n_chunks
            for flat in range(c * total // n_chunks, hi):
                b = flat // N
                i = flat % N
                o = agent_of[i] if n_obs == N else 0
                s, a, sn = s_t[now + b, o], a_t[now + b, o], sn_t[now + b, o]
                count = _up_neighbours(J, c, up_t, now + b, indptr, nbr, eid, i)
                _agent_step(theta, v, mu, sum_w, w_in, vmu_in, w_out, vmu_out, Lw, Lvmu, J, c, count, b, i, s, sn,
                            r_t[now + b, agent_of[i]], ratio_tab[s, a], alphas[t], q, Phi, sparse, ptr, idx, val,
                            cont, params)
            if t + 1 < T:  # task j of 2B: seed j // 2, observations (even j) or edges (odd j); spread over chunks
                for j in range(2 * B):
                    if j * n_chunks // (2 * B) == c:
                        sb = j // 2
                        if j % 2 == 0:
                            _step_observations(sb, nxt + sb, t + 1, fused, words, markov, current, d_prob, d_alias,
                                               sa_prob, sa_alias, R_sample, sigma, noise, s_blk, a_blk, sn_blk, r_blk,
                                               s_t, a_t, sn_t, r_t)
                        else:
                            n_up[sb] += _step_edges(sb, nxt + sb, t + 1, fused, words, p_edge, up_blk, up_t)
    # element by element: in a parallel function, numba loses a slice assignment to an array unpacked from a tuple
    for b in range(B):
        for k in range(3):
            for x in range(4):
                rng[b, k, x] = words[b, k, x]
    return T


load_quickly(_dgtd_by_seed, _dgtd_by_agent)


def feature_arrays(ctx, blk=None):
    """(Phi, sparse, CSR rows of Phi): sparse when rows hold at most a quarter of the features (tabular: one); the
    sparse kernels read the features from the CSR rows only, and get a row of zeros for Phi. The model's, once per
    run; a block's own rows (`SampleTable`), for that block."""

    def build(Phi=ctx.Phi):
        Phi = np.ascontiguousarray(Phi, dtype=np.float64)
        rows, cols = np.nonzero(Phi)  # row-major order: CSR rows without importing scipy.sparse
        indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=Phi.shape[0]))]).astype(np.int64)
        sparse = rows.size <= Phi.size // 4
        dense = np.zeros((1, Phi.shape[1])) if sparse else readonly(Phi)  # the model's Phi is read-only too
        return dense, sparse, indptr, cols.astype(np.int64), Phi[rows, cols].astype(np.float64)

    if getattr(blk, "table", None) is not None:
        return build(rows_of(ctx, blk)[0])
    return per_run(ctx, "phi", build)


LAYOUT = "auto"  # "seed" or "agent" force a layout (tests check both against the reference)


def by_agent(B: int, N: int, q: int) -> bool:
    """Spread agents rather than seeds over the cores when seeds are fewer than threads and agents are many."""
    from numba import get_num_threads

    if LAYOUT != "auto":
        return LAYOUT == "agent"
    return B < get_num_threads() and N * q >= 4096


@kernel("dgtd")
def dgtd_block(ctx, state, w_sum, alphas: np.ndarray, blk):
    """The contract of `dgtd.backends.reference.run_block`, compiled; ``blk`` is a `Block` of samples or `Draws`
    that the kernel draws itself (the same samples, never materialised)."""
    from numba import get_num_threads

    algorithm = ctx.algorithm
    order = storage_order(ctx)
    rows = (lambda x: x) if order is None else (lambda x: x[:, order[0]])
    back = (lambda x: x) if order is None else (lambda x: np.ascontiguousarray(x[:, order[1]]))
    B, N, q = state.w.shape
    copy = lambda x: np.array(rows(x), dtype=np.float64, order="C")  # noqa: E731  (updated in place: not the caller's)
    arrays = tuple(copy(x) for x in (state.theta, state.v, state.mu, w_sum))
    w, vmu = copy(state.w), copy(state.v + state.mu)
    shared = (w, vmu, np.zeros_like(w), np.zeros_like(vmu))
    sampler = sample_args(ctx, blk, B)
    boxes = (np.inf,) * 4 if algorithm.boxes is None else algorithm.boxes
    params = (float(ctx.gamma), float(algorithm.kappa), float(algorithm.rho), *(float(x) for x in boxes))
    ratio = rows_of(ctx, blk)[1]
    args = (np.ascontiguousarray(alphas), sampler, (*feature_arrays(ctx, blk), continuing_flags(ctx, blk)),
            readonly(ratio), storage_graph(ctx), params)
    if by_agent(B, N, q):
        steps = _dgtd_by_agent(arrays, shared, q, *args, 4 * get_num_threads())
    else:
        steps = _dgtd_by_seed(arrays, shared, q, *args)
    w = shared[2] if steps % 2 else shared[0]
    if isinstance(blk, Draws):
        _, rng, markov, current = sampler[:4]
        blk.settle(rng, current if markov else None, sampler[-1])
    theta, v, mu, sum_w = (back(x) for x in arrays)
    return DGTDState(theta, v, mu, back(w)), sum_w


dgtd_block.draws_samples = True  # the run loop may hand it `Draws` instead of a materialised `Block`
