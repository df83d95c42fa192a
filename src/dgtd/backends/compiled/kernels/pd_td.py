"""Compiled primal-dual distributed TD: `dgtd.algorithms.pd_td.PDTD.update`, line for line."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from dgtd.algorithms.pd_td import PDTDState
from dgtd.backends.compiled import kernel
from dgtd.backends.compiled.cache import load_quickly
from dgtd.backends.compiled.primitives import (add_rows, discount, f64, laplacian_rows, link_arrays, model_arrays,
                                              td_error, transition)


@njit(cache=True, parallel=True)
def _pd_td(w, mu, w_sum, alphas, eta, s_blk, a_blk, sn_blk, r_blk, Phi, ratio_tab, gamma, cont, up, indptr, nbr, eid):
    B, N, q = w.shape
    T, has_up = alphas.shape[0], up.shape[0] > 0
    for b in prange(B):
        Lw, Lmu = np.empty((N, q)), np.empty((N, q))
        deg = np.zeros(N, np.int64)  # unused by the plain Laplacian
        for t in range(T):
            add_rows(w, b, w_sum)
            laplacian_rows(w, b, up, t, has_up, indptr, nbr, eid, False, deg, Lw)
            laplacian_rows(mu, b, up, t, has_up, indptr, nbr, eid, False, deg, Lmu)
            alpha = alphas[t]
            for i in range(N):
                s, sn, ratio = transition(s_blk, a_blk, sn_blk, ratio_tab, t, b, i, N)
                gamma_ss = discount(gamma, cont, s, sn)  # gamma(s, s')
                delta = td_error(Phi, s, sn, r_blk[t, b, i], gamma_ss, w, b, i)
                for f in range(q):
                    w[b, i, f] += alpha * (ratio * delta * Phi[s, f] - eta * Lw[i, f] - eta * Lmu[i, f])
                    mu[b, i, f] += alpha * eta * Lw[i, f]


load_quickly(_pd_td)


@kernel("pd-td")
def pd_td_block(ctx, state, w_sum, alphas, blk):
    w, mu, w_sum = f64(state.w), f64(state.mu), f64(w_sum)
    _pd_td(w, mu, w_sum, np.ascontiguousarray(alphas), float(ctx.algorithm.eta), *model_arrays(ctx, blk),
           *link_arrays(ctx, blk))
    return PDTDState(w, mu), w_sum
