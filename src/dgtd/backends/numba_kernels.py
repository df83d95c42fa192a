"""Compiled kernels (numba): one fused loop per algorithm over a block of steps, seeds spread over the cores.

The sampler turns uniforms into samples with exactly the arithmetic of the NumPy reference
(`dgtd.run.sampling.alias_pick`, `reward_from_uniform`), and the update kernels apply the same updates, so
for the same seed both backends give the same numbers up to floating-point summation order. Everything is
compiled once and cached on disk (``cache=True``).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from dgtd.run.sampling import Block

NOISE_CODES = {"none": 0, "bernoulli": 1, "uniform": 2}


@njit(cache=True, inline="always")
def _alias(prob, alias, u):
    K = prob.shape[0]
    x = u * K
    j = min(np.int64(x), K - 1)
    if x - j < prob[j]:
        return j
    return alias[j]


@njit(cache=True, inline="always")
def _reward(mean, sigma, noise, u):
    if noise == 0:
        return mean
    if noise == 1:
        return sigma if u < mean / sigma else 0.0
    h = min(mean, sigma - mean)
    return mean + h * (2.0 * u - 1.0)


@njit(cache=True, inline="always")
def _clip(x, b):
    return -b if x < -b else (b if x > b else x)


@njit(cache=True, parallel=True)
def _sample_kernel(u_state, u_reward, u_edge, markov, current, d_prob, d_alias, sa_prob, sa_alias, R_sample,
                   sigma, noise, p_edge, s_out, a_out, sn_out, r_out, up_out):
    """Samples of a block: each (seed, observation) pair runs its own trajectory, so they are spread over the cores."""
    T, B, n_obs, width = u_state.shape
    N = R_sample.shape[0]
    S = R_sample.shape[1]
    for flat in prange(B * n_obs):
        b = flat // n_obs
        o = flat % n_obs
        for t in range(T):
            if markov:
                s = current[b, o]
            else:
                s = _alias(d_prob, d_alias, u_state[t, b, o, 0])
            j = _alias(sa_prob[s], sa_alias[s], u_state[t, b, o, width - 1])
            a = j // S
            s_out[t, b, o] = s
            a_out[t, b, o] = a
            sn_out[t, b, o] = j % S
            if markov:
                current[b, o] = j % S
            # Rewards of the agents that see this observation: agent o, or all agents on a shared trajectory.
            lo, hi = (o, o + 1) if n_obs == N else (0, N)
            for i in range(lo, hi):
                r = R_sample[i, s, a]
                r_out[t, b, i] = _reward(r, sigma, noise, u_reward[t, b, i]) if noise != 0 else r
    E = p_edge.shape[0]
    if up_out.shape[0] > 0:
        for flat in prange(T * B):
            t = flat // B
            b = flat % B
            for e in range(E):
                up_out[t, b, e] = u_edge[t, b, e] < p_edge[e]


def block_from_uniforms(problem, network, tables, U: dict, current):
    """Compiled twin of `dgtd.run.sampling.block_from_uniforms`."""
    T, B, n_obs, _ = U["state"].shape
    N = problem.n_agents
    markov = current is not None
    cur = np.array(current, dtype=np.int64) if markov else np.zeros((1, 1), np.int64)
    s, a, sn = (np.empty((T, B, n_obs), np.int64) for _ in range(3))
    r = np.empty((T, B, N))
    up = np.empty((T, B, network.n_edges), np.bool_) if "edge" in U else np.empty((0, 0, 0), np.bool_)
    _sample_kernel(np.ascontiguousarray(U["state"]), U.get("reward", np.zeros((0, 0, 0))), U.get("edge", np.zeros((0, 0, 0))),
                   markov, cur, tables.d_prob, tables.d_alias, tables.sa_prob, tables.sa_alias,
                   np.ascontiguousarray(problem.R_sample), float(problem.sigma), NOISE_CODES[problem.reward_noise],
                   np.asarray(network.p, dtype=np.float64), s, a, sn, r, up)
    return Block(s, a, sn, r, up if "edge" in U else None), (cur if markov else None)


# No fastmath: with reassociation or fused multiply-adds, the rounding of a sum depends on how LLVM vectorised
# one compiled specialisation, and the same seed gave results one ulp apart in different processes.
FAST = False


@njit(cache=True, inline="always", fastmath=FAST)
def _laplacian_row(i, b, t, Z, up, has_up, indptr, nbr, eid, L):
    """L = (L(k) Z)_i = |N_i(k)| Z_i - sum_{j in N_i(k)} Z_j (Algorithm 1's neighbour sums) for the packed rows
    Z = (w, v + mu): the w update needs L v + L mu = L (v + mu), so two rows per neighbour are read, not three."""
    m = Z.shape[2]
    L[:] = 0.0
    count = 0
    for p in range(indptr[i], indptr[i + 1]):
        if (not has_up) or up[t, b, eid[p]]:
            zj = Z[b, nbr[p]]
            count += 1
            for f in range(m):
                L[f] += zj[f]
    zi = Z[b, i]
    for f in range(m):
        L[f] = count * zi[f] - L[f]


@njit(cache=True, inline="always", fastmath=FAST)
def _agent_step(b, i, s, sn, r, ratio, alpha, in_tail, theta, VM, Z, Z_out, L, sum_all, sum_tail, Phi, sparse, ptr,
                idx, val, gamma, kappa, rho, boxes):
    """Algorithm 1 lines 7-9 for agent i of seed b.

    Z[b, i] = (w, v + mu) at step k (what neighbours read), Z_out[b, i] receives them at step k + 1;
    VM[b, i] = (v, mu) and theta[b, i] depend on agent i's own variables only and are updated in place.
    L = (L(k) w, L(k) (v + mu)) rows. With sparse features (CSR rows ptr/idx/val of Phi) the TD terms cost
    O(nnz(phi) + nnz(phi')) instead of O(q).
    """
    q = theta.shape[2]
    b_th, b_v, b_mu, b_w = boxes[0], boxes[1], boxes[2], boxes[3]
    th, vm, zi, zo = theta[b, i], VM[b, i], Z[b, i], Z_out[b, i]
    phi_theta = 0.0
    phi_w = 0.0
    phin_w = 0.0
    if sparse:
        for p in range(ptr[s], ptr[s + 1]):
            phi_theta += val[p] * th[idx[p]]
            phi_w += val[p] * zi[idx[p]]
        for p in range(ptr[sn], ptr[sn + 1]):
            phin_w += val[p] * zi[idx[p]]
    else:
        phi, phin = Phi[s], Phi[sn]
        for f in range(q):
            phi_theta += phi[f] * th[f]
            phi_w += phi[f] * zi[f]
            phin_w += phin[f] * zi[f]
    # Line 7 (theta): phi phi^T theta + ratio (phi phi^T w - gamma phi phi'^T w - phi r) = phi * c_theta
    c_theta = phi_theta + ratio * (phi_w - gamma * phin_w - r)
    rt = ratio * phi_theta
    sa = sum_all[b, i]
    for f in range(q):
        sa[f] += zi[f]
    if in_tail:
        st = sum_tail[b, i]
        for f in range(q):
            st[f] += zi[f]
    # Line 8 (w): ratio (phi - gamma phi') phi^T theta - (L v)_i - (L mu)_i - kappa (L w)_i - rho w, projected (line 9)
    if not sparse:
        phi, phin = Phi[s], Phi[sn]
        for f in range(q):
            wf = zi[f]
            g_w = rt * (phi[f] - gamma * phin[f]) - L[q + f] - kappa * L[f] - rho * wf
            zo[f] = min(max(wf + alpha * g_w, -b_w), b_w)
            th[f] = min(max(th[f] - alpha * (phi[f] * c_theta), -b_th), b_th)
    else:
        for f in range(q):
            wf = zi[f]
            zo[f] = wf + alpha * (-L[q + f] - kappa * L[f] - rho * wf)
        for p in range(ptr[s], ptr[s + 1]):
            f = idx[p]
            th[f] = min(max(th[f] - alpha * (val[p] * c_theta), -b_th), b_th)
            zo[f] += alpha * (rt * val[p])
        for p in range(ptr[sn], ptr[sn + 1]):
            zo[idx[p]] -= alpha * (rt * gamma * val[p])
        for f in range(q):
            zo[f] = min(max(zo[f], -b_w), b_w)
    # Line 7 (v) and line 8 (mu), projected (line 9); neighbours will read their sum
    for f in range(q):
        vf, muf, Lw = vm[f], vm[q + f], L[f]
        v_new = min(max(vf - alpha * (vf - Lw), -b_v), b_v)
        mu_new = min(max(muf - alpha * (-Lw + rho * muf), -b_mu), b_mu)
        vm[f] = v_new
        vm[q + f] = mu_new
        zo[q + f] = v_new + mu_new


@njit(cache=True, parallel=True, fastmath=FAST)
def _dgtd_by_seed(theta, VM, Z, sum_all, sum_tail, k0, tail_start, alphas, s_blk, a_blk, sn_blk, r_blk, up,
                  Phi, sparse, ptr, idx, val, ratio_tab, gamma, kappa, rho, boxes, indptr, nbr, eid):
    """Seeds spread over the cores; within a seed, steps and agents run in order (small N, many seeds)."""
    B, N, m = Z.shape
    T = alphas.shape[0]
    n_obs = s_blk.shape[2]
    has_up = up.shape[0] > 0
    for b in prange(B):
        L = np.empty((N, m))
        for t in range(T):
            for i in range(N):
                _laplacian_row(i, b, t, Z, up, has_up, indptr, nbr, eid, L[i])
            for i in range(N):
                o = i if n_obs == N else 0
                s, a = s_blk[t, b, o], a_blk[t, b, o]
                # All Laplacians of step k are taken first, so in-place writes are safe (Jacobi form).
                _agent_step(b, i, s, sn_blk[t, b, o], r_blk[t, b, i], ratio_tab[s, a], alphas[t], k0 + t >= tail_start,
                            theta, VM, Z, Z, L[i], sum_all, sum_tail, Phi, sparse, ptr, idx, val, gamma, kappa, rho,
                            boxes)


@njit(cache=True, parallel=True, fastmath=FAST)
def _dgtd_by_agent(theta, VM, Z, Z2, sum_all, sum_tail, k0, tail_start, alphas, s_blk, a_blk, sn_blk, r_blk, up,
                   Phi, sparse, ptr, idx, val, ratio_tab, gamma, kappa, rho, boxes, indptr, nbr, eid, n_chunks):
    """Agents spread over the cores at every step (large N, few seeds): the rows neighbours read, Z = (w, v + mu),
    are double-buffered so that every agent reads step k's values while others write step k + 1's. Returns the
    number of buffer swaps (odd: the result is in Z2)."""
    B, N, m = Z.shape
    T = alphas.shape[0]
    n_obs = s_blk.shape[2]
    has_up = up.shape[0] > 0
    total = B * N
    for t in range(T):
        Zi, Zo = (Z, Z2) if t % 2 == 0 else (Z2, Z)
        for c in prange(n_chunks):
            L = np.empty(m)
            for flat in range(c * total // n_chunks, (c + 1) * total // n_chunks):
                b = flat // N
                i = flat % N
                o = i if n_obs == N else 0
                s, a = s_blk[t, b, o], a_blk[t, b, o]
                _laplacian_row(i, b, t, Zi, up, has_up, indptr, nbr, eid, L)
                _agent_step(b, i, s, sn_blk[t, b, o], r_blk[t, b, i], ratio_tab[s, a], alphas[t], k0 + t >= tail_start,
                            theta, VM, Zi, Zo, L, sum_all, sum_tail, Phi, sparse, ptr, idx, val, gamma, kappa, rho,
                            boxes)
    return T


def csr_adjacency(edges: np.ndarray, n_nodes: int):
    """Neighbour lists with edge ids: for node i, nbr[indptr[i]:indptr[i+1]] and their edges eid[...]."""
    E = edges.shape[0]
    ends = np.concatenate([edges[:, 0], edges[:, 1]])
    others = np.concatenate([edges[:, 1], edges[:, 0]])
    ids = np.concatenate([np.arange(E), np.arange(E)])
    order = np.lexsort((others, ends))
    indptr = np.zeros(n_nodes + 1, np.int64)
    np.add.at(indptr, ends + 1, 1)
    return np.cumsum(indptr), others[order].astype(np.int64), ids[order].astype(np.int64)


def graph_arrays(ctx):
    """CSR arrays of the base graph, computed once per run context."""
    cache = ctx.__dict__.setdefault("_numba_cache", {})
    if "csr" not in cache:
        cache["csr"] = csr_adjacency(ctx.network.base.edges, ctx.network.n_nodes)
    return cache["csr"]


def _up(blk: Block):
    return np.empty((0, 0, 0), np.bool_) if blk.up is None else np.ascontiguousarray(blk.up)


def feature_arrays(ctx):
    """Phi dense and as CSR rows; sparse when rows hold at most a quarter of the features (tabular: one)."""
    cache = ctx.__dict__.setdefault("_numba_cache", {})
    if "phi" not in cache:
        Phi = np.ascontiguousarray(ctx.Phi, dtype=np.float64)
        rows, cols = np.nonzero(Phi)  # row-major order: CSR rows without importing scipy.sparse
        indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=Phi.shape[0]))]).astype(np.int64)
        sparse = rows.size <= Phi.size // 4
        cache["phi"] = (Phi, sparse, indptr, cols.astype(np.int64), Phi[rows, cols].astype(np.float64))
    return cache["phi"]


LAYOUT = "auto"  # "seed" or "agent" force a layout (tests check both against the reference)


def by_agent(B: int, N: int, q: int) -> bool:
    """Spread agents rather than seeds over the cores when seeds are fewer than threads and agents are many."""
    from numba import get_num_threads

    if LAYOUT != "auto":
        return LAYOUT == "agent"
    return B < get_num_threads() and N * q >= 4096


def dgtd_block(ctx, state, sums, k0: int, alphas: np.ndarray, blk: Block):
    """Same contract as `dgtd.backends.numpy_ref.dgtd_block`, compiled."""
    from numba import get_num_threads

    from dgtd.algorithms.dgtd import DGTDState

    theta = np.array(state.theta, dtype=np.float64, order="C")
    VM = np.concatenate([state.v, state.mu], axis=2)
    Z = np.concatenate([state.w, state.v + state.mu], axis=2)  # what neighbours read: one contiguous row each
    sum_all, sum_tail = sums["all"].copy(), sums["tail"].copy()
    indptr, nbr, eid = graph_arrays(ctx)
    Phi, sparse, ptr, idx, val = feature_arrays(ctx)
    common = (np.ascontiguousarray(alphas), blk.s, blk.a, blk.s_next, blk.r, _up(blk), Phi, sparse, ptr, idx, val,
              np.ascontiguousarray(ctx.ratio), float(ctx.gamma), float(ctx.algorithm.kappa), float(ctx.algorithm.rho),
              np.asarray(ctx.boxes, dtype=np.float64), indptr, nbr, eid)
    B, N, q = theta.shape
    if by_agent(B, N, q):
        Z2 = np.empty_like(Z)
        if _dgtd_by_agent(theta, VM, Z, Z2, sum_all, sum_tail, k0, ctx.tail_start, *common, 4 * get_num_threads()) % 2:
            Z = Z2
    else:
        _dgtd_by_seed(theta, VM, Z, sum_all, sum_tail, k0, ctx.tail_start, *common)
    state = DGTDState(theta, np.ascontiguousarray(VM[:, :, :q]), np.ascontiguousarray(VM[:, :, q:]),
                      np.ascontiguousarray(Z[:, :, :q]))
    return state, {"all": sum_all, "tail": sum_tail}


BLOCKS = {"dgtd": dgtd_block}

from dgtd.backends.numba_baselines import BLOCKS as _BASELINE_BLOCKS  # noqa: E402  (baselines: gtd2, tdc, ...)

BLOCKS.update(_BASELINE_BLOCKS)
