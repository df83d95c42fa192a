"""Plain NumPy reference kernels: the readable version every faster backend is tested against.

A kernel advances all seeds and agents over a block of steps [k0, k0 + T) from that block's samples
(`dgtd.run.sampling.Block`), vectorised over seeds and agents; only the time loop is in Python. It also adds
every w_k to ``sums["all"]``, the running sum behind the averaged iterates of `prop:convergence1` (the run
loop takes the tail average as the difference of two of its values).
"""

from __future__ import annotations

import numpy as np

from dgtd.algorithms import dgtd as dgtd_alg
from dgtd.run.sampling import Block


def dgtd_block(ctx, state, sums, k0: int, alphas: np.ndarray, blk: Block):
    """Advance Algorithm 1 over steps k0 .. k0 + len(alphas) - 1; returns (state, sums)."""
    sums = {k: v.copy() for k, v in sums.items()}
    for t in range(len(alphas)):
        s, a, sn = blk.s[t], blk.a[t], blk.s_next[t]
        mask = None if blk.up is None else blk.up[t]
        sums["all"] += dgtd_alg.DGTD.estimate(state)  # the running sum of w_k for the averaged iterate
        state = dgtd_alg.update(
            state, ctx.Phi[s], ctx.Phi[sn], blk.r[t], ctx.ratio[s, a], lambda X: ctx.lap(X, mask),
            alphas[t], ctx.gamma, ctx.algorithm.kappa, ctx.algorithm.rho, ctx.boxes,
        )
    return state, sums


BLOCKS = {"dgtd": dgtd_block}

from dgtd.backends.numpy_baselines import BLOCKS as _BASELINE_BLOCKS  # noqa: E402  (baselines: gtd2, tdc, ...)

BLOCKS.update(_BASELINE_BLOCKS)
