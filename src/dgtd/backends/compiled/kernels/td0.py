"""Compiled centralised TD(0): `dgtd.algorithms.td0.TD0.update`, line for line, seeds spread over the cores."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from dgtd.algorithms.td0 import TD0State
from dgtd.backends.compiled import kernel
from dgtd.backends.compiled.cache import load_quickly
from dgtd.backends.compiled.primitives import add_rows, discount, f64, model_arrays, td_error, transition


@njit(cache=True, parallel=True)
def _td0(w, w_sum, alphas, s_blk, a_blk, sn_blk, r_blk, Phi, ratio_tab, gamma, cont):
    B, _, q = w.shape
    T, N = alphas.shape[0], r_blk.shape[2]
    for b in prange(B):
        dw = np.empty(q)
        for t in range(T):
            add_rows(w, b, w_sum)
            dw[:] = 0.0
            for i in range(N):
                s, sn, ratio = transition(s_blk, a_blk, sn_blk, ratio_tab, t, b, i, N)
                gamma_ss = discount(gamma, cont, s, sn)  # gamma(s, s')
                delta = td_error(Phi, s, sn, r_blk[t, b, i], gamma_ss, w, b, 0)
                for f in range(q):
                    dw[f] += ratio * delta * Phi[s, f]  # ratio_i delta_i phi_i
            for f in range(q):
                w[b, 0, f] += alphas[t] * (dw[f] / N)  # the mean over the N transitions


load_quickly(_td0)


@kernel("td0")
def td0_block(ctx, state, w_sum, alphas, blk):
    w, w_sum = f64(state.w), f64(w_sum)
    _td0(w, w_sum, np.ascontiguousarray(alphas), *model_arrays(ctx, blk))
    return TD0State(w), w_sum
