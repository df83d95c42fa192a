"""The reference backend: one plain NumPy loop that runs any algorithm's ``update`` over a block of steps.

It is the readable definition every compiled kernel is tested against. For each step it adds the estimate w_k to
the running sum behind the averaged iterates (Proposition 2 of the paper; the run loop takes the tail average as
the difference of two of its values), builds the step's `Sample`, has the channel turn what every agent sends into
what every agent hears, and calls ``update``. Vectorised over seeds and agents; only the time loop is in Python.
"""

from __future__ import annotations

import numpy as np

from dgtd.channels.base import copied
from dgtd.samples import Block


def run_block(ctx, state, channel_state, w_sum: np.ndarray, alphas: np.ndarray, blk: Block):
    """Advance ``ctx.algorithm`` over the len(alphas) steps of ``blk``: returns (state, channel state, w_sum), new
    values all."""
    algorithm, channel = ctx.algorithm, ctx.channel
    w_sum, channel_state = w_sum.copy(), copied(channel_state)  # the channel may update what it holds in place
    Phi, ratio, continuing = (ctx.Phi, ctx.ratio, ctx.continuing) if blk.table is None else blk.table
    for t in range(len(alphas)):
        w_sum += algorithm.estimate(state)
        up = None if blk.up is None else blk.up[t]
        inbox, channel_state = channel.deliver(channel_state, ctx.arcs, algorithm.sends(state), up)
        new = algorithm.update(state, blk.sample(t, Phi, ratio, ctx.gamma, continuing), inbox, alphas[t])
        if inbox.awake is not None:  # an asleep agent keeps its state (`dgtd.channels.Imperfect`)
            new = new._make(np.where(inbox.awake[:, :, None], x, old) for x, old in zip(new, state))
        state = new
    return state, channel_state, w_sum
