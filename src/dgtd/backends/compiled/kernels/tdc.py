"""Compiled centralised TDC: `dgtd.algorithms.tdc.TDC.update`, line for line, seeds spread over the cores."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from dgtd.algorithms.gtd2 import GTDState
from dgtd.backends.compiled import kernel
from dgtd.backends.compiled.cache import load_quickly
from dgtd.backends.compiled.primitives import (add_rows, aux_params, aux_step, discount, f64,
                                              feature_dot, model_arrays, td_error, transition)


@njit(cache=True, parallel=True)
def _tdc(w, theta, w_sum, alphas, aux, s_blk, a_blk, sn_blk, r_blk, Phi, ratio_tab, gamma, cont):
    B, _, q = w.shape
    T, N = alphas.shape[0], r_blk.shape[2]
    for b in prange(B):
        dw, dtheta = np.empty(q), np.empty(q)
        for t in range(T):
            add_rows(w, b, w_sum)
            dw[:] = 0.0
            dtheta[:] = 0.0
            for i in range(N):
                s, sn, ratio = transition(s_blk, a_blk, sn_blk, ratio_tab, t, b, i, N)
                gamma_ss = discount(gamma, cont, s, sn)  # gamma(s, s')
                delta = td_error(Phi, s, sn, r_blk[t, b, i], gamma_ss, w, b, 0)
                phi_theta = feature_dot(Phi, s, theta, b, 0)
                for f in range(q):
                    # w_terms: ratio (delta phi - gamma phi' phi^T theta); theta_terms as GTD2's
                    dw[f] += ratio * delta * Phi[s, f] - gamma_ss * (ratio * phi_theta) * Phi[sn, f]
                    dtheta[f] += (ratio * delta - phi_theta) * Phi[s, f]
            alpha = alphas[t]
            beta_k = aux_step(alpha, aux[0], aux[1], aux[2])  # the auxiliary step (`GTDConfig.aux_step`)
            for f in range(q):
                w[b, 0, f] += alpha * (dw[f] / N)
                theta[b, 0, f] += beta_k * (dtheta[f] / N)


load_quickly(_tdc)


@kernel("tdc")
def tdc_block(ctx, state, w_sum, alphas, blk):
    w, theta, w_sum = f64(state.w), f64(state.theta), f64(w_sum)
    _tdc(w, theta, w_sum, np.ascontiguousarray(alphas), aux_params(ctx.algorithm), *model_arrays(ctx, blk))
    return GTDState(w, theta), w_sum
