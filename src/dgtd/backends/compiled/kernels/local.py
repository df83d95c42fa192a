"""Compiled local GTD2: `dgtd.algorithms.local.Local.update`, every agent on its own reward, seeds over the cores."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from dgtd.algorithms.gtd2 import GTDState
from dgtd.backends.compiled import kernel
from dgtd.backends.compiled.cache import load_quickly
from dgtd.backends.compiled.kernels.gtd2 import gtd2_terms
from dgtd.backends.compiled.primitives import (add_rows, aux_params, aux_step, discount, f64,
                                              feature_dot, model_arrays, td_error, transition)


@njit(cache=True, parallel=True)
def _local(w, theta, w_sum, alphas, aux, s_blk, a_blk, sn_blk, r_blk, Phi, ratio_tab, gamma, cont):
    B, N, q = w.shape
    T = alphas.shape[0]
    for b in prange(B):
        dw, dtheta = np.empty(q), np.empty(q)
        for t in range(T):
            add_rows(w, b, w_sum)
            alpha = alphas[t]
            beta_k = aux_step(alpha, aux[0], aux[1], aux[2])  # the auxiliary step (`GTDConfig.aux_step`)
            for i in range(N):  # agent i reads only its own w_i, theta_i: updating in place is the Jacobi step
                s, sn, ratio = transition(s_blk, a_blk, sn_blk, ratio_tab, t, b, i, N)
                gamma_ss = discount(gamma, cont, s, sn)  # gamma(s, s')
                delta = td_error(Phi, s, sn, r_blk[t, b, i], gamma_ss, w, b, i)
                dw[:] = 0.0
                dtheta[:] = 0.0
                gtd2_terms(Phi, s, sn, ratio, delta, feature_dot(Phi, s, theta, b, i), gamma_ss, dw, dtheta)
                for f in range(q):
                    w[b, i, f] += alpha * dw[f]
                    theta[b, i, f] += beta_k * dtheta[f]


load_quickly(_local)


@kernel("local")
def local_block(ctx, state, w_sum, alphas, blk):
    w, theta, w_sum = f64(state.w), f64(state.theta), f64(w_sum)
    _local(w, theta, w_sum, np.ascontiguousarray(alphas), aux_params(ctx.algorithm), *model_arrays(ctx, blk))
    return GTDState(w, theta), w_sum
