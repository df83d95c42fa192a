"""Compiled TD(0) with gradient tracking: `dgtd.algorithms.td_tracking.TDTracking.update`, line for line."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from dgtd.algorithms.td_tracking import TrackingState
from dgtd.backends.compiled import kernel
from dgtd.backends.compiled.cache import load_quickly
from dgtd.backends.compiled.primitives import (add_rows, degrees, discount, f64, laplacian_rows, link_arrays,
                                              model_arrays, td_error, transition)


@njit(cache=True, parallel=True)
def _td_tracking(w, z, g_prev, w_sum, alphas, s_blk, a_blk, sn_blk, r_blk, Phi, ratio_tab, gamma, cont, up, indptr, nbr,
                 eid):
    B, N, q = w.shape
    T, has_up = alphas.shape[0], up.shape[0] > 0
    for b in prange(B):
        Lw, Lz = np.empty((N, q)), np.empty((N, q))
        deg = np.zeros(N, np.int64)
        for t in range(T):
            add_rows(w, b, w_sum)
            degrees(up, t, b, has_up, indptr, eid, deg)
            laplacian_rows(w, b, up, t, has_up, indptr, nbr, eid, True, deg, Lw)
            laplacian_rows(z, b, up, t, has_up, indptr, nbr, eid, True, deg, Lz)
            for i in range(N):
                s, sn, ratio = transition(s_blk, a_blk, sn_blk, ratio_tab, t, b, i, N)
                gamma_ss = discount(gamma, cont, s, sn)  # gamma(s, s')
                delta = td_error(Phi, s, sn, r_blk[t, b, i], gamma_ss, w, b, i)
                for f in range(q):
                    g = ratio * delta * Phi[s, f]  # g_i(k)
                    z_new = z[b, i, f] - Lz[i, f] + g - g_prev[b, i, f]  # the tracker z_i(k)
                    w[b, i, f] = w[b, i, f] - Lw[i, f] + alphas[t] * z_new
                    z[b, i, f] = z_new
                    g_prev[b, i, f] = g


load_quickly(_td_tracking)


@kernel("td-tracking")
def td_tracking_block(ctx, state, w_sum, alphas, blk):
    w, z, g, w_sum = f64(state.w), f64(state.z), f64(state.g), f64(w_sum)
    _td_tracking(w, z, g, w_sum, np.ascontiguousarray(alphas), *model_arrays(ctx, blk), *link_arrays(ctx, blk))
    return TrackingState(w, z, g), w_sum
