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
    T, B, n_obs, width = u_state.shape
    N = R_sample.shape[0]
    S = R_sample.shape[1]
    E = p_edge.shape[0]
    for b in prange(B):
        for t in range(T):
            for o in range(n_obs):
                if markov:
                    s = current[b, o]
                else:
                    s = _alias(d_prob, d_alias, u_state[t, b, o, 0])
                idx = _alias(sa_prob[s], sa_alias[s], u_state[t, b, o, width - 1])
                s_out[t, b, o] = s
                a_out[t, b, o] = idx // S
                sn_out[t, b, o] = idx % S
                if markov:
                    current[b, o] = idx % S
            for i in range(N):
                o = i if n_obs == N else 0
                r = R_sample[i, s_out[t, b, o], a_out[t, b, o]]
                r_out[t, b, i] = _reward(r, sigma, noise, u_reward[t, b, i]) if noise != 0 else r
            if up_out.shape[0] > 0:
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


@njit(cache=True)
def _laplacian(X, up, t, b, has_up, indptr, nbr, eid, out):
    """out_i = sum over edges {i, j} up at step t of (X_i - X_j), node by node through CSR neighbour lists."""
    N, q = X.shape
    for i in range(N):
        for f in range(q):
            out[i, f] = 0.0
        for p in range(indptr[i], indptr[i + 1]):
            if (not has_up) or up[t, b, eid[p]]:
                j = nbr[p]
                for f in range(q):
                    out[i, f] += X[i, f] - X[j, f]


@njit(cache=True, parallel=True)
def _dgtd_kernel(theta, v, mu, w, sum_all, sum_tail, k0, tail_start, alphas, s_blk, a_blk, sn_blk, r_blk, up,
                 Phi, ratio_tab, gamma, kappa, rho, boxes, indptr, nbr, eid):
    B, N, q = w.shape
    T = alphas.shape[0]
    n_obs = s_blk.shape[2]
    has_up = up.shape[0] > 0
    b_th, b_v, b_mu, b_w = boxes[0], boxes[1], boxes[2], boxes[3]
    for b in prange(B):
        Lw = np.empty((N, q))
        Lv = np.empty((N, q))
        Lmu = np.empty((N, q))
        for t in range(T):
            k = k0 + t
            alpha = alphas[t]
            _laplacian(w[b], up, t, b, has_up, indptr, nbr, eid, Lw)
            _laplacian(v[b], up, t, b, has_up, indptr, nbr, eid, Lv)
            _laplacian(mu[b], up, t, b, has_up, indptr, nbr, eid, Lmu)
            for i in range(N):
                o = i if n_obs == N else 0
                s, a, sn = s_blk[t, b, o], a_blk[t, b, o], sn_blk[t, b, o]
                ratio = ratio_tab[s, a]
                r = r_blk[t, b, i]
                phi_theta = 0.0
                phi_w = 0.0
                phin_w = 0.0
                for f in range(q):
                    phi_theta += Phi[s, f] * theta[b, i, f]
                    phi_w += Phi[s, f] * w[b, i, f]
                    phin_w += Phi[sn, f] * w[b, i, f]
                c_theta = phi_theta + ratio * (phi_w - gamma * phin_w - r)
                rt = ratio * phi_theta
                for f in range(q):
                    wf = w[b, i, f]
                    sum_all[b, i, f] += wf
                    if k >= tail_start:
                        sum_tail[b, i, f] += wf
                    # Algorithm 1 line 7 (theta, v), line 8 (mu, w), line 9 (projection)
                    g_theta = Phi[s, f] * c_theta
                    g_v = v[b, i, f] - Lw[i, f]
                    g_mu = -Lw[i, f] + rho * mu[b, i, f]
                    g_w = rt * (Phi[s, f] - gamma * Phi[sn, f]) - Lv[i, f] - Lmu[i, f] - kappa * Lw[i, f] - rho * wf
                    theta[b, i, f] = _clip(theta[b, i, f] - alpha * g_theta, b_th)
                    v[b, i, f] = _clip(v[b, i, f] - alpha * g_v, b_v)
                    mu[b, i, f] = _clip(mu[b, i, f] - alpha * g_mu, b_mu)
                    w[b, i, f] = _clip(wf + alpha * g_w, b_w)


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


def dgtd_block(ctx, state, sums, k0: int, alphas: np.ndarray, blk: Block):
    """Same contract as `dgtd.backends.numpy_ref.dgtd_block`, compiled."""
    from dgtd.algorithms.dgtd import DGTDState

    theta, v, mu, w = (np.array(x, dtype=np.float64, order="C") for x in state)
    sum_all, sum_tail = sums["all"].copy(), sums["tail"].copy()
    indptr, nbr, eid = graph_arrays(ctx)
    _dgtd_kernel(
        theta, v, mu, w, sum_all, sum_tail, k0, ctx.tail_start, np.ascontiguousarray(alphas),
        blk.s, blk.a, blk.s_next, blk.r, _up(blk), np.ascontiguousarray(ctx.Phi), np.ascontiguousarray(ctx.ratio),
        float(ctx.gamma), float(ctx.algorithm.kappa), float(ctx.algorithm.rho), np.asarray(ctx.boxes, dtype=np.float64),
        indptr, nbr, eid,
    )
    return DGTDState(theta, v, mu, w), {"all": sum_all, "tail": sum_tail}


BLOCKS = {"dgtd": dgtd_block}

from dgtd.backends.numba_baselines import BLOCKS as _BASELINE_BLOCKS  # noqa: E402  (baselines: gtd2, tdc, ...)

BLOCKS.update(_BASELINE_BLOCKS)
