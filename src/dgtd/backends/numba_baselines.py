"""Compiled block kernels of the baselines: the same updates as `dgtd.backends.numpy_baselines`, fused.

One loop per algorithm over a block of steps, seeds spread over the cores; the arithmetic follows the
pure update functions of `dgtd.algorithms` term by term, so both backends agree to rounding.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from dgtd.backends.numba_cache import load_quickly
from dgtd.run.sampling import Block


@njit(cache=True)
def _mix(X, up, t, b, has_up, indptr, nbr, eid, metropolis, deg, out):
    """out_i = sum over edges {i, j} up at step t of c_ij (X_i - X_j); c_ij = 1 (the Laplacian L(k)) or the
    Metropolis weight 1 / (1 + max(d_i, d_j)) (the weighted Laplacian of consensus TD(0))."""
    N, q = X.shape
    if metropolis:
        for i in range(N):
            d = 0
            for p in range(indptr[i], indptr[i + 1]):
                if (not has_up) or up[t, b, eid[p]]:
                    d += 1
            deg[i] = d
    for i in range(N):
        for f in range(q):
            out[i, f] = 0.0
        for p in range(indptr[i], indptr[i + 1]):
            if (not has_up) or up[t, b, eid[p]]:
                j = nbr[p]
                c = 1.0 / (1.0 + max(deg[i], deg[j])) if metropolis else 1.0
                for f in range(q):
                    out[i, f] += c * (X[i, f] - X[j, f])


@njit(cache=True, inline="always")
def _dots(Phi, s, sn, x, y):
    """(phi(s)^T x, phi(s')^T x, phi(s)^T y)."""
    a = 0.0
    b = 0.0
    c = 0.0
    for f in range(x.shape[0]):
        a += Phi[s, f] * x[f]
        b += Phi[sn, f] * x[f]
        c += Phi[s, f] * y[f]
    return a, b, c


@njit(cache=True, inline="always")
def _add_sums(w, b, sum_all):
    for e in range(w.shape[1]):
        for f in range(w.shape[2]):
            sum_all[b, e, f] += w[b, e, f]


@njit(cache=True, parallel=True)
def _gtd_kernel(kind, w, theta, sum_all, alphas, eta, s_blk, a_blk, sn_blk, r_blk,
                Phi, ratio_tab, gamma):
    """kind 0: TD(0), 1: GTD2, 2: TDC. Centralised when w has one row (mean over the N transitions), else
    per agent (`local`). theta is unused by TD(0)."""
    B, n_est, q = w.shape
    T = alphas.shape[0]
    n_obs = s_blk.shape[2]
    N = r_blk.shape[2]
    central = n_est == 1
    scale = 1.0 / N if central else 1.0
    for b in prange(B):
        dw = np.empty((n_est, q))
        dth = np.empty((n_est, q))
        for t in range(T):
            _add_sums(w, b, sum_all)
            dw[:] = 0.0
            dth[:] = 0.0
            for i in range(N):
                o = i if n_obs == N else 0
                e = 0 if central else i
                s, sn = s_blk[t, b, o], sn_blk[t, b, o]
                rho = ratio_tab[s, a_blk[t, b, o]]
                phi_w, phin_w, phi_th = _dots(Phi, s, sn, w[b, e], theta[b, e])
                delta = r_blk[t, b, i] + gamma * phin_w - phi_w
                for f in range(q):
                    if kind == 0:  # TD(0): ratio delta phi
                        dw[e, f] += rho * delta * Phi[s, f]
                    elif kind == 1:  # GTD2: ratio (phi - gamma phi') phi^T theta
                        dw[e, f] += rho * phi_th * (Phi[s, f] - gamma * Phi[sn, f])
                    else:  # TDC: ratio (delta phi - gamma phi' phi^T theta)
                        dw[e, f] += rho * delta * Phi[s, f] - gamma * rho * phi_th * Phi[sn, f]
                    if kind != 0:  # auxiliary: (ratio delta - phi^T theta) phi
                        dth[e, f] += (rho * delta - phi_th) * Phi[s, f]
            alpha = alphas[t]
            for e in range(n_est):
                for f in range(q):
                    w[b, e, f] += alpha * (dw[e, f] * scale)
                    theta[b, e, f] += eta * alpha * (dth[e, f] * scale)


@njit(cache=True, parallel=True)
def _distributed_td_kernel(kind, w, mu, sum_all, alphas, eta, s_blk, a_blk, sn_blk,
                           r_blk, up, Phi, ratio_tab, gamma, indptr, nbr, eid):
    """kind 0: consensus TD(0) (Metropolis mixing); kind 1: pd-td (Laplacian primal-dual). mu unused by kind 0."""
    B, N, q = w.shape
    T = alphas.shape[0]
    n_obs = s_blk.shape[2]
    has_up = up.shape[0] > 0
    for b in prange(B):
        Lw = np.empty((N, q))
        Lmu = np.empty((N, q))
        deg = np.zeros(N, np.int64)
        for t in range(T):
            _add_sums(w, b, sum_all)
            alpha = alphas[t]
            _mix(w[b], up, t, b, has_up, indptr, nbr, eid, kind == 0, deg, Lw)
            if kind == 1:
                _mix(mu[b], up, t, b, has_up, indptr, nbr, eid, False, deg, Lmu)
            for i in range(N):
                o = i if n_obs == N else 0
                s, sn = s_blk[t, b, o], sn_blk[t, b, o]
                rho = ratio_tab[s, a_blk[t, b, o]]
                phi_w, phin_w, _ = _dots(Phi, s, sn, w[b, i], w[b, i])
                c = rho * (r_blk[t, b, i] + gamma * phin_w - phi_w)
                for f in range(q):
                    if kind == 0:  # W(k) w - ... = w - L_W(k) w + alpha ratio delta phi
                        w[b, i, f] = w[b, i, f] - Lw[i, f] + alpha * (c * Phi[s, f])
                    else:
                        w[b, i, f] += alpha * (c * Phi[s, f] - eta * Lw[i, f] - eta * Lmu[i, f])
                        mu[b, i, f] += alpha * eta * Lw[i, f]


load_quickly(_gtd_kernel, _distributed_td_kernel)


def _f64(x):
    return np.array(x, dtype=np.float64, order="C")


def _gtd_block(kind: int, ctx, state, sums, k0, alphas, blk: Block):
    w = _f64(state.w)
    theta = _f64(state.theta) if kind else np.zeros_like(w)
    sum_all = sums["all"].copy()
    eta = float(getattr(ctx.algorithm, "eta", 1.0))
    _gtd_kernel(kind, w, theta, sum_all, np.ascontiguousarray(alphas), eta,
                blk.s, blk.a, blk.s_next, blk.r, np.ascontiguousarray(ctx.Phi), np.ascontiguousarray(ctx.ratio),
                float(ctx.gamma))
    new = state._replace(w=w, theta=theta) if kind else state._replace(w=w)
    return new, {"all": sum_all}


def td0_block(ctx, state, sums, k0, alphas, blk):
    return _gtd_block(0, ctx, state, sums, k0, alphas, blk)


def gtd2_block(ctx, state, sums, k0, alphas, blk):
    return _gtd_block(1, ctx, state, sums, k0, alphas, blk)


def tdc_block(ctx, state, sums, k0, alphas, blk):
    return _gtd_block(2, ctx, state, sums, k0, alphas, blk)


def local_block(ctx, state, sums, k0, alphas, blk):
    return _gtd_block(1, ctx, state, sums, k0, alphas, blk)


def _distributed_block(kind: int, ctx, state, sums, k0, alphas, blk: Block):
    from dgtd.backends.numba_graph import graph_arrays
    from dgtd.backends.numba_sampling import up_mask

    w = _f64(state.w)
    mu = _f64(state.mu) if kind else np.zeros_like(w)
    sum_all = sums["all"].copy()
    indptr, nbr, eid = graph_arrays(ctx)
    _distributed_td_kernel(kind, w, mu, sum_all, np.ascontiguousarray(alphas),
                           float(getattr(ctx.algorithm, "eta", 0.0)), blk.s, blk.a, blk.s_next, blk.r, up_mask(blk),
                           np.ascontiguousarray(ctx.Phi), np.ascontiguousarray(ctx.ratio), float(ctx.gamma),
                           indptr, nbr, eid)
    new = state._replace(w=w, mu=mu) if kind else state._replace(w=w)
    return new, {"all": sum_all}


def consensus_td0_block(ctx, state, sums, k0, alphas, blk):
    return _distributed_block(0, ctx, state, sums, k0, alphas, blk)


def pd_td_block(ctx, state, sums, k0, alphas, blk):
    return _distributed_block(1, ctx, state, sums, k0, alphas, blk)


BLOCKS = {
    "td0": td0_block,
    "gtd2": gtd2_block,
    "tdc": tdc_block,
    "local": local_block,
    "consensus-td0": consensus_td0_block,
    "pd-td": pd_td_block,
}
