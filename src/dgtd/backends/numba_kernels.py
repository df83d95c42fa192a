"""Compiled kernels (numba): one fused loop per algorithm over a block of steps, seeds spread over the cores.

The DGTD kernels draw their own samples from the seeds' PCG64 streams (`dgtd.backends.numba_sampling`), the
same samples as the NumPy reference, and apply the same updates, so for the same seed both backends give the
same numbers up to floating-point summation order. Everything is compiled once and cached on disk
(``cache=True``). numba keys each cached kernel by its own file only: after editing a helper that the kernels
inline from numba_sampling, numba_rng or numba_simd, delete the __pycache__ folder here
(installed copies are rewritten whole on upgrade, so only working trees are concerned).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from dgtd.backends.numba_cache import load_quickly
from dgtd.backends.numba_graph import per_run, storage_graph, storage_order
from dgtd.backends.numba_sampling import _step_edges, _step_observations, _step_samples, sample_args
from dgtd.backends.numba_simd import _dense_updates, _dots3, _laplacian_rows
from dgtd.run.sampling import Draws


@njit(cache=True, inline="always")
def _clip(x, b):
    return -b if x < -b else (b if x > b else x)


# No fastmath: with reassociation or fused multiply-adds, the rounding of a sum depends on how LLVM vectorised
# one compiled specialisation, and the same seed gave results one ulp apart in different processes. Dot
# products, which LLVM would then leave scalar, and the neighbour sums, whose running row LLVM would store
# once per neighbour, are written in vector instructions by hand (`numba_simd`), and so are the dense
# updates, in one pass over the features instead of five (the memory-bound large graphs gain most).
#
# Three rules keep the loops left to LLVM (sparse features) vectorised. Elements of the shared arrays are
# indexed directly (Z[b, j, f]), never through row views (Z[b, j]): numba counts references to every view with
# an atomic update, and two threads updating the same count stall each other. A loop writes one half of an
# array at most (theta, v and mu have arrays of their own): when one loop writes two halves of the same array,
# LLVM cannot prove that they do not overlap and falls back to scalar code, three times slower. And offsets into
# the second half of a packed row are unsigned (`_hi`), so that numba emits no wrap-around test for negative
# indices in the way.


@njit(cache=True, inline="always")
def _hi(q, f):
    """Index of element f of the second half of a packed row of 2q: unsigned, so it needs no wrap-around test."""
    return np.uint64(q) + np.uint64(f)


@njit(cache=True, inline="always")
def _laplacian_row(Z, b, i, up, ub, indptr, nbr, eid, L, l, J):
    """L[l] = (L(k) Z)_i = |N_i(k)| Z_i - sum_{j in N_i(k)} Z_j (Algorithm 1's neighbour sums) for the packed rows
    Z[b, j] = (w_j, v_j + mu_j) of seed b, over the edges of agent i that are up (row ub of the step's edge mask
    ``up``; all ones for a fixed graph). The w update needs L v + L mu = L (v + mu): two vectors per neighbour,
    read as one contiguous row. J is scratch for the up neighbours' rows (as long as the largest degree)."""
    count = 0
    for p in range(indptr[i], indptr[i + 1]):  # without a branch: edges are up at random, a branch mispredicts
        J[count] = nbr[p]
        count += up[ub, eid[p]]
    _laplacian_rows(Z, b, i, J, count, L, l)


@njit(cache=True, inline="always")
def _max_degree(indptr):
    d = 1
    for k in range(indptr.shape[0] - 1):
        d = max(d, indptr[k + 1] - indptr[k])
    return d


@njit(cache=True, inline="always")
def _agent_step(b, i, s, sn, r, ratio, alpha, in_tail, theta, V, MU, Z, Zo, L, l, sum_all, sum_tail, Phi, sparse,
                ptr, idx, val, gamma, kappa, rho, boxes):
    """Algorithm 1 lines 7-9 for agent i of seed b.

    Z[b, i] = (w, v + mu) at step k, packed (what neighbours read); Zo[b, i] receives them at step k + 1 (Zo is
    Z itself when every Laplacian row of the step was taken first). theta, V, MU depend on agent i's own
    variables only and are updated in place. L[l] = ((L(k) w)_i, (L(k) v + L(k) mu)_i). With sparse features
    (CSR rows ptr/idx/val of Phi) the TD terms cost O(nnz(phi) + nnz(phi')) instead of O(q).
    """
    q = theta.shape[2]
    b_th, b_v, b_mu, b_w = boxes[0], boxes[1], boxes[2], boxes[3]
    if sparse:
        phi_theta = 0.0
        phi_w = 0.0
        phin_w = 0.0
        for p in range(ptr[s], ptr[s + 1]):
            phi_theta += val[p] * theta[b, i, idx[p]]
            phi_w += val[p] * Z[b, i, idx[p]]
        for p in range(ptr[sn], ptr[sn + 1]):
            phin_w += val[p] * Z[b, i, idx[p]]
    else:
        phi_theta, phi_w, phin_w = _dots3(Phi, s, sn, theta, Z, b, i, q)
    # Line 7 (theta): phi phi^T theta + ratio (phi phi^T w - gamma phi phi'^T w - phi r) = phi * c_theta
    c_theta = phi_theta + ratio * (phi_w - gamma * phin_w - r)
    rt = ratio * phi_theta
    if not sparse:  # lines 7-9 in one pass over the features, element by element as below (`numba_simd`)
        _dense_updates(Z, Zo, b, i, V, MU, theta, sum_all, sum_tail, in_tail, L, l, Phi, s, sn, alpha, rho, kappa,
                       gamma, rt, c_theta, b_th, b_v, b_mu, b_w)
        return
    for f in range(q):
        sum_all[b, i, f] += Z[b, i, f]
    if in_tail:
        for f in range(q):
            sum_tail[b, i, f] += Z[b, i, f]
    # Line 7 (v) and line 8 (mu), projected (line 9); neighbours will read their sum
    for f in range(q):
        vf, muf, lw = V[b, i, f], MU[b, i, f], L[l, f]
        v_new = _clip(vf - alpha * (vf - lw), b_v)
        mu_new = _clip(muf - alpha * (-lw + rho * muf), b_mu)
        V[b, i, f] = v_new
        MU[b, i, f] = mu_new
        Zo[b, i, _hi(q, f)] = v_new + mu_new
    # Line 8 (w): ratio (phi - gamma phi') phi^T theta - (L v)_i - (L mu)_i - kappa (L w)_i - rho w, projected (line 9);
    # the TD part phi and phi' touch only their nonzero features
    for f in range(q):
        wf = Z[b, i, f]
        Zo[b, i, f] = wf + alpha * (-L[l, _hi(q, f)] - kappa * L[l, f] - rho * wf)
    for p in range(ptr[s], ptr[s + 1]):
        f = idx[p]
        theta[b, i, f] = _clip(theta[b, i, f] - alpha * (val[p] * c_theta), b_th)
        Zo[b, i, f] += alpha * (rt * val[p])
    for p in range(ptr[sn], ptr[sn + 1]):
        Zo[b, i, idx[p]] -= alpha * (rt * gamma * val[p])
    for f in range(q):
        Zo[b, i, f] = _clip(Zo[b, i, f], b_w)


@njit(cache=True, parallel=True)
def _dgtd_by_seed(theta, V, MU, Z, sum_all, sum_tail, k0, tail_start, alphas, fused, rng, markov, current, d_prob,
                  d_alias, sa_prob, sa_alias, R_sample, sigma, noise, p_edge, s_blk, a_blk, sn_blk, r_blk, up_blk,
                  n_up, Phi, sparse, ptr, idx, val, ratio_tab, gamma, kappa, rho, boxes, indptr, nbr, eid, agent_of):
    """Seeds spread over the cores; within a seed, steps and agents run in order (small N, many seeds): each
    step samples, takes every agent's Laplacian rows, then updates the agents in place (Jacobi form). Row i
    of the state arrays holds agent agent_of[i] (`storage_order`)."""
    B, N, m = Z.shape
    T = alphas.shape[0]
    n_obs, E = current.shape[1], indptr[N] // 2
    degree = _max_degree(indptr)
    for b in prange(B):
        L = np.empty((N, m))
        J = np.empty(degree, np.int64)
        s_t, a_t, sn_t = np.empty((1, n_obs), np.int64), np.empty((1, n_obs), np.int64), np.empty((1, n_obs), np.int64)
        r_t = np.empty((1, N))
        up_t = np.ones((1, E), np.bool_)
        for t in range(T):
            n_up[b] += _step_samples(b, 0, t, fused, rng, markov, current, d_prob, d_alias, sa_prob, sa_alias, R_sample,
                                     sigma, noise, p_edge, s_blk, a_blk, sn_blk, r_blk, up_blk, s_t, a_t, sn_t, r_t,
                                     up_t)
            for i in range(N):
                _laplacian_row(Z, b, i, up_t, 0, indptr, nbr, eid, L, i, J)
            for i in range(N):
                o = agent_of[i] if n_obs == N else 0
                s, a = s_t[0, o], a_t[0, o]
                _agent_step(b, i, s, sn_t[0, o], r_t[0, agent_of[i]], ratio_tab[s, a], alphas[t], k0 + t >= tail_start,
                            theta, V, MU, Z, Z, L, i, sum_all, sum_tail, Phi, sparse, ptr, idx, val, gamma, kappa,
                            rho, boxes)


@njit(cache=True, parallel=True)
def _dgtd_by_agent(theta, V, MU, Z, Z2, sum_all, sum_tail, k0, tail_start, alphas, fused, rng, markov, current, d_prob,
                   d_alias, sa_prob, sa_alias, R_sample, sigma, noise, p_edge, s_blk, a_blk, sn_blk, r_blk, up_blk,
                   n_up, Phi, sparse, ptr, idx, val, ratio_tab, gamma, kappa, rho, boxes, indptr, nbr, eid, agent_of,
                   n_chunks):
    """Agents spread over the cores at every step (large N, few seeds). The rows neighbours read, (w, v + mu),
    are double-buffered so that every agent reads step k's values while others write step k + 1's. Samples
    are double-buffered too: while the agents update with step k's, the chunks also draw step k + 1's, each
    seed's state and reward streams in one chunk and its edge stream in another (a stream is sequential, but
    the streams are independent), so that no core waits while another samples. Returns the number of buffer
    swaps (odd: the result is in Z2)."""
    B, N, m = Z.shape
    T = alphas.shape[0]
    n_obs, E = current.shape[1], indptr[N] // 2
    degree = _max_degree(indptr)
    total = B * N
    s_t, a_t, sn_t = np.empty((2 * B, n_obs), np.int64), np.empty((2 * B, n_obs), np.int64), np.empty((2 * B, n_obs), np.int64)
    r_t = np.empty((2 * B, N))
    up_t = np.ones((2 * B, E), np.bool_)
    # each stream's words on cache lines of their own: two cores advance streams of the same seed at once
    words = np.zeros((B, 3, 16), np.uint64)
    words[:, :, :4] = rng
    for b in range(B if T > 0 else 0):  # step 0's samples (none for an empty block: the streams stay put)
        n_up[b] += _step_samples(b, b, 0, fused, words, markov, current, d_prob, d_alias, sa_prob, sa_alias, R_sample,
                                 sigma, noise, p_edge, s_blk, a_blk, sn_blk, r_blk, up_blk, s_t, a_t, sn_t, r_t, up_t)
    for t in range(T):
        Zi, Zo = (Z, Z2) if t % 2 == 0 else (Z2, Z)
        now, nxt = (t % 2) * B, ((t + 1) % 2) * B  # rows of this step's samples and the next step's
        for c in prange(n_chunks):
            L = np.empty((1, m))
            J = np.empty(degree, np.int64)
            hi = (c + 1) * total // n_chunks
            for flat in range(c * total // n_chunks, hi):
                b = flat // N
                i = flat % N
                o = agent_of[i] if n_obs == N else 0
                s, a = s_t[now + b, o], a_t[now + b, o]
                _laplacian_row(Zi, b, i, up_t, now + b, indptr, nbr, eid, L, 0, J)
                _agent_step(b, i, s, sn_t[now + b, o], r_t[now + b, agent_of[i]], ratio_tab[s, a], alphas[t],
                            k0 + t >= tail_start, theta, V, MU, Zi, Zo, L, 0, sum_all, sum_tail, Phi, sparse, ptr, idx,
                            val, gamma, kappa, rho, boxes)
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
    rng[:, :, :] = words[:, :, :4]
    return T


load_quickly(_dgtd_by_seed, _dgtd_by_agent)


def feature_arrays(ctx):
    """Phi dense and as CSR rows; sparse when rows hold at most a quarter of the features (tabular: one)."""

    def build():
        Phi = np.ascontiguousarray(ctx.Phi, dtype=np.float64)
        rows, cols = np.nonzero(Phi)  # row-major order: CSR rows without importing scipy.sparse
        indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=Phi.shape[0]))]).astype(np.int64)
        sparse = rows.size <= Phi.size // 4
        return Phi, sparse, indptr, cols.astype(np.int64), Phi[rows, cols].astype(np.float64)

    return per_run(ctx, "phi", build)


LAYOUT = "auto"  # "seed" or "agent" force a layout (tests check both against the reference)


def by_agent(B: int, N: int, q: int) -> bool:
    """Spread agents rather than seeds over the cores when seeds are fewer than threads and agents are many."""
    from numba import get_num_threads

    if LAYOUT != "auto":
        return LAYOUT == "agent"
    return B < get_num_threads() and N * q >= 4096


def dgtd_block(ctx, state, sums, k0: int, alphas: np.ndarray, blk):
    """Same contract as `dgtd.backends.numpy_ref.dgtd_block`, compiled; ``blk`` is a `Block` of samples or
    `Draws` that the kernel draws itself (the same samples, never materialised)."""
    from numba import get_num_threads

    from dgtd.algorithms.dgtd import DGTDState

    order = storage_order(ctx)
    # C order throughout: `_dots3` reads rows as contiguous vectors
    rows = (lambda x: np.array(x, dtype=np.float64, order="C")) if order is None else (
        lambda x: np.ascontiguousarray(x[:, order[0]], dtype=np.float64))
    theta, V, MU = (rows(x) for x in state[:3])
    # what neighbours read: one row (w, v + mu) each
    Z = np.ascontiguousarray(np.concatenate([rows(state.w), rows(state.v + state.mu)], axis=2))
    sum_all, sum_tail = rows(sums["all"]), rows(sums["tail"])
    indptr, nbr, eid, agent_of = storage_graph(ctx)
    Phi, sparse, ptr, idx, val = feature_arrays(ctx)
    B, N, q = theta.shape
    sampling = sample_args(ctx, blk, B)
    common = (np.ascontiguousarray(alphas), *sampling, Phi, sparse, ptr, idx, val, np.ascontiguousarray(ctx.ratio),
              float(ctx.gamma), float(ctx.algorithm.kappa), float(ctx.algorithm.rho),
              np.asarray(ctx.boxes, dtype=np.float64), indptr, nbr, eid, agent_of)
    if by_agent(B, N, q):
        Z2 = np.empty_like(Z)
        if _dgtd_by_agent(theta, V, MU, Z, Z2, sum_all, sum_tail, k0, ctx.tail_start, *common, 4 * get_num_threads()) % 2:
            Z = Z2
    else:
        _dgtd_by_seed(theta, V, MU, Z, sum_all, sum_tail, k0, ctx.tail_start, *common)
    if isinstance(blk, Draws):
        _, rng, markov, current = sampling[:4]
        blk.settle(rng, current if markov else None, sampling[-1])
    back = (lambda x: np.ascontiguousarray(x)) if order is None else (lambda x: np.ascontiguousarray(x[:, order[1]]))
    return (DGTDState(back(theta), back(V), back(MU), back(Z[:, :, :q])),
            {"all": back(sum_all), "tail": back(sum_tail)})


dgtd_block.draws_samples = True  # the run loop may hand it `Draws` instead of a materialised `Block`

BLOCKS = {"dgtd": dgtd_block}

from dgtd.backends.numba_baselines import BLOCKS as _BASELINE_BLOCKS  # noqa: E402  (baselines: gtd2, tdc, ...)

BLOCKS.update(_BASELINE_BLOCKS)
