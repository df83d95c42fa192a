"""The compiled DGTD kernel (Algorithm 1, `dgtd.algorithms.dgtd.DGTD.update`): one fused loop over a block of steps.

The kernels draw their own samples from the seeds' PCG64 streams (`dgtd.backends.compiled.sampling`), the same
samples as the reference backend, and apply the same updates, so for the same seed both backends give the same
numbers up to floating-point summation order. Two layouts: seeds spread over the cores (`_dgtd_by_seed`, small N)
or agents (`_dgtd_by_agent`, large N and few seeds).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from dgtd.algorithms.dgtd import DGTDState
from dgtd.backends.compiled import kernel
from dgtd.backends.compiled.cache import load_quickly
from dgtd.backends.compiled.graph import per_run, storage_graph, storage_order
from dgtd.backends.compiled.sampling import _step_edges, _step_observations, _step_samples, sample_args
from dgtd.backends.compiled.simd import (MU, SUM_W, THETA, V, VMU, W, _agent_pass, _dots3, from_blocks, shared_index,
                                         state_index, to_blocks)
from dgtd.samples import Draws


@njit(cache=True, inline="always")
def _clip(x, b):
    return -b if x < -b else (b if x > b else x)


# No fastmath: with reassociation or fused multiply-adds, the rounding of a sum depends on how LLVM vectorised
# one compiled specialisation, and the same seed gave results one ulp apart in different processes. The dense
# agent step is written in vector instructions by hand (`dgtd.backends.compiled.simd._agent_pass`), in one pass over the
# features. Elements of the shared arrays are indexed directly (S[b, i, k]), never through row views (S[b, i]):
# numba counts references to every view with an atomic update, and two threads updating the same count stall
# each other.


@njit(cache=True, inline="always")
def _up_neighbours(J, up, ub, indptr, nbr, eid, i):
    """The rows of agent i's neighbours whose edges are up (row ub of the step's edge mask ``up``; all ones for a
    fixed graph) into J; returns how many. Without a branch: edges are up at random, a branch mispredicts."""
    count = 0
    for p in range(indptr[i], indptr[i + 1]):
        J[count] = nbr[p]
        count += up[ub, eid[p]]
    return count


@njit(cache=True, inline="always")
def _max_degree(indptr):
    d = 1
    for k in range(indptr.shape[0] - 1):
        d = max(d, indptr[k + 1] - indptr[k])
    return d


@njit(cache=True)
def _td_scalars(dots, ratio, r, gamma):
    """(c_theta, ratio phi^T theta) from the TD terms (phi^T theta, phi^T w, phi'^T w): Algorithm 1 line 7's theta
    update is phi phi^T theta + ratio (phi phi^T w - gamma phi phi'^T w - phi r) = phi * c_theta, and line 8's TD
    part of w is ratio (phi - gamma phi') phi^T theta."""
    phi_theta, phi_w, phin_w = dots
    return phi_theta + ratio * (phi_w - gamma * phin_w - r), ratio * phi_theta


@njit(cache=True)
def _row_value(ptr, idx, val, s, f):
    """phi_f(s) from the CSR rows of Phi (a row's features are in increasing order and few)."""
    for p in range(ptr[s], ptr[s + 1]):
        if idx[p] == f:
            return val[p]
    return 0.0


@njit(cache=True)
def _sparse_td_feature(b, i, f, phs, phsn, c_theta, rt, alpha, S, Zi, Zo, J, count, gamma, kappa, rho, b_th, b_w):
    """Feature f of w and theta with its nonzero phi_f(s) = phs or phi_f(s') = phsn, after a pass without the TD
    terms (`_sparse_step`): the arithmetic of `numba_simd._agent_pass`, from the same inputs."""
    c = float(count)
    w = Zi[b, i, shared_index(f, W)]
    lw, lvm = c * w, c * Zi[b, i, shared_index(f, VMU)]
    for n in range(count):
        lw -= Zi[b, J[n], shared_index(f, W)]
        lvm -= Zi[b, J[n], shared_index(f, VMU)]
    g_w = rt * (phs - gamma * phsn) - lvm - kappa * lw - rho * w
    Zo[b, i, shared_index(f, W)] = _clip(w + alpha * g_w, b_w)
    if phs != 0.0:  # theta_f moves only where phi_f is nonzero
        S[b, i, state_index(f, THETA)] = _clip(S[b, i, state_index(f, THETA)] - alpha * (phs * c_theta), b_th)


@njit(cache=True)
def _sparse_step(b, i, s, sn, r, ratio, alpha, S, Zi, Zo, J, count, q, ptr, idx, val, gamma, kappa, rho, boxes):
    """Algorithm 1 lines 7-9 for agent i of seed b with sparse features (CSR rows ptr/idx/val of Phi): the dot
    products cost O(nnz(phi) + nnz(phi')), the rest O(q) in vector instructions. A pass of `_agent_pass` without
    the TD terms does everything that does not depend on phi, and the features where phi or phi' is nonzero are
    then done again with their values."""
    phi_theta = 0.0
    phi_w = 0.0
    phin_w = 0.0
    for p in range(ptr[s], ptr[s + 1]):
        phi_theta += val[p] * S[b, i, state_index(idx[p], THETA)]
        phi_w += val[p] * Zi[b, i, shared_index(idx[p], W)]
    for p in range(ptr[sn], ptr[sn + 1]):
        phin_w += val[p] * Zi[b, i, shared_index(idx[p], W)]
    c_theta, rt = _td_scalars((phi_theta, phi_w, phin_w), ratio, r, gamma)
    b_th, b_w = boxes[0], boxes[3]
    _agent_pass(Zi, Zo, S, b, i, J, count, None, 0, 0, None, None, q, alpha, rho, kappa, gamma, rt, c_theta, b_th,
                boxes[1], boxes[2], b_w)
    for p in range(ptr[s], ptr[s + 1]):
        _sparse_td_feature(b, i, idx[p], val[p], _row_value(ptr, idx, val, sn, idx[p]), c_theta, rt, alpha, S, Zi, Zo,
                           J, count, gamma, kappa, rho, b_th, b_w)
    for p in range(ptr[sn], ptr[sn + 1]):
        if _row_value(ptr, idx, val, s, idx[p]) == 0.0:  # not done above
            _sparse_td_feature(b, i, idx[p], 0.0, val[p], c_theta, rt, alpha, S, Zi, Zo, J, count, gamma, kappa,
                               rho, b_th, b_w)


@njit(cache=True, inline="always")
def _dense_step(b, i, s, sn, s_next, sn_next, r, ratio, alpha, dots, S, Zi, Zo, J, count, q, Phi, gamma, kappa,
                rho, boxes):
    """Algorithm 1 lines 7-9 for agent i of seed b with dense features, from its TD terms ``dots`` at step k;
    returns those of step k + 1 (from the features of s_next, sn_next; zeros when they are None: `_agent_pass`)."""
    c_theta, rt = _td_scalars(dots, ratio, r, gamma)
    return _agent_pass(Zi, Zo, S, b, i, J, count, Phi, s, sn, s_next, sn_next, q, alpha, rho, kappa, gamma, rt, c_theta,
                       boxes[0], boxes[1], boxes[2], boxes[3])


@njit(cache=True, parallel=True)
def _dgtd_by_seed(S, Z, Z2, q, alphas, fused, rng, markov, current, d_prob, d_alias, sa_prob, sa_alias, R_sample,
                  sigma, noise, p_edge, s_blk, a_blk, sn_blk, r_blk, up_blk, n_up, Phi, sparse, ptr, idx, val,
                  ratio_tab, gamma, kappa, rho, boxes, indptr, nbr, eid, agent_of):
    """Seeds spread over the cores; within a seed, steps and agents run in order (small N, many seeds). The
    shared rows, which neighbours read, are double-buffered (Z at even steps, Z2 at odd ones), so every agent
    reads step k's while writing step k + 1's (Jacobi form). Each step first draws the next step's samples, so
    that an agent's pass can leave behind the TD terms of its next step (`_agent_pass`). Row i of the arrays
    holds agent agent_of[i] (`storage_order`). Returns the number of steps (odd: the result is in Z2)."""
    B, N = Z.shape[0], Z.shape[1]
    T = alphas.shape[0]
    n_obs, E = current.shape[1], indptr[N] // 2
    degree = _max_degree(indptr)
    for b in prange(B):
        J = np.empty(degree, np.int64)
        dots = np.zeros((N, 3))
        s_t, a_t, sn_t = np.empty((2, n_obs), np.int64), np.empty((2, n_obs), np.int64), np.empty((2, n_obs), np.int64)
        r_t = np.empty((2, N))
        up_t = np.ones((2, E), np.bool_)
        for t in range(T):
            # this step's samples are there (at t = 0, drawn now, with its TD terms), and the next step's are drawn
            # ahead (not past the block: the streams must stay at its end); one call site compiles once
            for u in range(0 if t == 0 else t + 1, min(t + 2, T)):
                n_up[b] += _step_samples(b, u % 2, u, fused, rng, markov, current, d_prob, d_alias, sa_prob, sa_alias,
                                         R_sample, sigma, noise, p_edge, s_blk, a_blk, sn_blk, r_blk, up_blk, s_t, a_t,
                                         sn_t, r_t, up_t)
            if t == 0 and not sparse:
                for i in range(N):
                    o = agent_of[i] if n_obs == N else 0
                    dots[i, 0], dots[i, 1], dots[i, 2] = _dots3(Phi, s_t[0, o], sn_t[0, o], S, Z, b, i, q)
            Zi, Zo = (Z, Z2) if t % 2 == 0 else (Z2, Z)
            now, nxt = t % 2, (t + 1) % 2
            for i in range(N):
                count = _up_neighbours(J, up_t, now, indptr, nbr, eid, i)
                o = agent_of[i] if n_obs == N else 0
                s, a, sn = s_t[now, o], a_t[now, o], sn_t[now, o]
                r = r_t[now, agent_of[i]]
                if sparse:
                    _sparse_step(b, i, s, sn, r, ratio_tab[s, a], alphas[t], S, Zi, Zo, J, count, q, ptr, idx, val,
                                 gamma, kappa, rho, boxes)
                else:
                    # after the block's last step the next TD terms are not needed; s_next = s keeps one compiled pass
                    s_next, sn_next = (s_t[nxt, o], sn_t[nxt, o]) if t + 1 < T else (s, sn)
                    dots[i, 0], dots[i, 1], dots[i, 2] = _dense_step(
                        b, i, s, sn, s_next, sn_next, r, ratio_tab[s, a], alphas[t],
                        (dots[i, 0], dots[i, 1], dots[i, 2]), S, Zi, Zo, J, count, q, Phi, gamma, kappa, rho, boxes)
    return T


@njit(cache=True, parallel=True)
def _dgtd_by_agent(S, Z, Z2, q, alphas, fused, rng, markov, current, d_prob, d_alias, sa_prob, sa_alias, R_sample,
                   sigma, noise, p_edge, s_blk, a_blk, sn_blk, r_blk, up_blk, n_up, Phi, sparse, ptr, idx, val,
                   ratio_tab, gamma, kappa, rho, boxes, indptr, nbr, eid, agent_of, n_chunks):
    """Agents spread over the cores at every step (large N, few seeds). The shared rows, which neighbours read,
    are double-buffered so that every agent reads step k's values while others write step k + 1's. Samples
    are double-buffered too: while the agents update with step k's, the chunks also draw step k + 1's, each
    seed's state and reward streams in one chunk and its edge stream in another (a stream is sequential, but
    the streams are independent), so that no core waits while another samples. Returns the number of buffer
    swaps (odd: the result is in Z2)."""
    B, N = Z.shape[0], Z.shape[1]
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
            J = np.empty(degree, np.int64)
            hi = (c + 1) * total // n_chunks
            for flat in range(c * total // n_chunks, hi):
                b = flat // N
                i = flat % N
                o = agent_of[i] if n_obs == N else 0
                s, a, sn = s_t[now + b, o], a_t[now + b, o], sn_t[now + b, o]
                r = r_t[now + b, agent_of[i]]
                count = _up_neighbours(J, up_t, now + b, indptr, nbr, eid, i)
                if sparse:
                    _sparse_step(b, i, s, sn, r, ratio_tab[s, a], alphas[t], S, Zi, Zo, J, count, q, ptr, idx, val,
                                 gamma, kappa, rho, boxes)
                else:
                    _dense_step(b, i, s, sn, None, None, r, ratio_tab[s, a], alphas[t],
                                _dots3(Phi, s, sn, S, Zi, b, i, q), S, Zi, Zo, J, count, q, Phi, gamma, kappa,
                                rho, boxes)
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
    """(Phi, sparse, CSR rows of Phi): sparse when rows hold at most a quarter of the features (tabular: one); the
    sparse kernels read the features from the CSR rows only (`_sparse_step`), and get a row of zeros for Phi."""

    def build():
        Phi = np.ascontiguousarray(ctx.Phi, dtype=np.float64)
        rows, cols = np.nonzero(Phi)  # row-major order: CSR rows without importing scipy.sparse
        indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=Phi.shape[0]))]).astype(np.int64)
        sparse = rows.size <= Phi.size // 4
        dense = np.zeros((1, Phi.shape[1])) if sparse else Phi
        return dense, sparse, indptr, cols.astype(np.int64), Phi[rows, cols].astype(np.float64)

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
    # the blocked rows of `simd`: the agents' state rows, and the shared rows neighbours read (w, v + mu)
    S = to_blocks([rows(state.theta), rows(state.v), rows(state.mu), rows(w_sum)], q)
    Z = to_blocks([rows(state.w), rows(state.v + state.mu)], q)
    Z2 = np.zeros_like(Z)
    indptr, nbr, eid, agent_of = storage_graph(ctx)
    Phi, sparse, ptr, idx, val = feature_arrays(ctx)
    sampling = sample_args(ctx, blk, B)
    boxes = (np.inf,) * 4 if algorithm.boxes is None else algorithm.boxes
    common = (np.ascontiguousarray(alphas), *sampling, Phi, sparse, ptr, idx, val, np.ascontiguousarray(ctx.ratio),
              float(ctx.gamma), float(algorithm.kappa), float(algorithm.rho), np.asarray(boxes, dtype=np.float64),
              indptr, nbr, eid, agent_of)
    if by_agent(B, N, q):
        steps = _dgtd_by_agent(S, Z, Z2, q, *common, 4 * get_num_threads())
    else:
        steps = _dgtd_by_seed(S, Z, Z2, q, *common)
    if steps % 2:
        Z = Z2
    if isinstance(blk, Draws):
        _, rng, markov, current = sampling[:4]
        blk.settle(rng, current if markov else None, sampling[-1])
    theta, v, mu, sum_w = (back(from_blocks(S, var, 4, q)) for var in (THETA, V, MU, SUM_W))
    return DGTDState(theta, v, mu, back(from_blocks(Z, W, 2, q))), sum_w


dgtd_block.draws_samples = True  # the run loop may hand it `Draws` instead of a materialised `Block`
