"""Compiled consensus TD(0): `dgtd.algorithms.consensus_td0.ConsensusTD0.update`, line for line."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from dgtd.algorithms.consensus_td0 import ConsensusState
from dgtd.backends.compiled import kernel
from dgtd.backends.compiled.cache import load_quickly
from dgtd.backends.compiled.primitives import (add_rows, degrees, discount, f64, laplacian_rows, link_arrays,
                                              model_arrays, td_error, transition)


@njit(cache=True, parallel=True)
def _consensus_td0(w, w_sum, alphas, s_blk, a_blk, sn_blk, r_blk, Phi, ratio_tab, gamma, cont, up, indptr, nbr, eid):
    B, N, q = w.shape
    T, has_up = alphas.shape[0], up.shape[0] > 0
    for b in prange(B):
        Lw = np.empty((N, q))
        deg = np.zeros(N, np.int64)
        for t in range(T):
            add_rows(w, b, w_sum)
            degrees(up, t, b, has_up, indptr, eid, deg)
            laplacian_rows(w, b, up, t, has_up, indptr, nbr, eid, True, deg, Lw)  # L_W(k) w, before any w moves
            for i in range(N):
                s, sn, ratio = transition(s_blk, a_blk, sn_blk, ratio_tab, t, b, i, N)
                gamma_ss = discount(gamma, cont, s, sn)  # gamma(s, s')
                delta = td_error(Phi, s, sn, r_blk[t, b, i], gamma_ss, w, b, i)
                for f in range(q):  # w - L_W(k) w + alpha ratio delta phi
                    w[b, i, f] = w[b, i, f] - Lw[i, f] + alphas[t] * (ratio * delta * Phi[s, f])


load_quickly(_consensus_td0)


@kernel("consensus-td0")
def consensus_td0_block(ctx, state, w_sum, alphas, blk):
    w, w_sum = f64(state.w), f64(w_sum)
    _consensus_td0(w, w_sum, np.ascontiguousarray(alphas), *model_arrays(ctx, blk), *link_arrays(ctx, blk))
    return ConsensusState(w), w_sum
