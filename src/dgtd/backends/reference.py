"""The reference backend: one plain NumPy loop that runs any algorithm's ``update`` over a block of steps.

It is the readable definition every compiled kernel is tested against: for each step it adds the estimate w_k to
the running sum behind the averaged iterates (Proposition 2 of the paper; the run loop takes the tail average as
the difference of two of its values), builds the step's `Sample` and `Links`, and calls ``update``. Vectorised
over seeds and agents; only the time loop is in Python.
"""

from __future__ import annotations

import numpy as np

from dgtd.graphs.links import Links
from dgtd.samples import Block


def run_block(ctx, state, w_sum: np.ndarray, alphas: np.ndarray, blk: Block):
    """Advance ``ctx.algorithm`` over the len(alphas) steps of ``blk``; returns (state, w_sum), both new arrays."""
    algorithm = ctx.algorithm
    w_sum = w_sum.copy()
    n_seeds = blk.r.shape[1]
    Phi, ratio, continuing = (ctx.Phi, ctx.ratio, ctx.continuing) if blk.table is None else blk.table
    for t in range(len(alphas)):
        w_sum += algorithm.estimate(state)
        links = Links(ctx.lap, None if blk.up is None else blk.up[t], n_seeds)
        state = algorithm.update(state, blk.sample(t, Phi, ratio, ctx.gamma, continuing), links, alphas[t])
    return state, w_sum
