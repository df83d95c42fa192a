"""Where a run's agents are held: all in this process (`Whole`), or spread over the ranks of an MPI job
(`dgtd.backends.mpi.Ranks`, the same methods). The run loop holds the rows ``agents`` of every per-agent array and
the arcs ``arc_ids`` of the channel's state, and combines what it holds through these methods, so that its metrics
and checkpoints are the same numbers however the agents are laid out."""

from __future__ import annotations

import numpy as np

from dgtd.channels.base import per_arc_fields
from dgtd.problems.exact import ordered_consensus_error, ordered_sum


class Whole:
    """Every agent in this process, in its own numbering (``agents`` None); sums over the agents taken in the
    storage order of the compiled kernels (`dgtd.backends.compiled.graph.storage_order`), the order the ranks hold
    them in."""

    agents = arc_ids = None
    root = True

    def __init__(self, ctx):
        from dgtd.backends.compiled.graph import storage_order

        order = storage_order(ctx)
        self.order = None if order is None else order[0]
        self.arcs = ctx.arcs

    def rows(self, x: np.ndarray) -> np.ndarray:
        return x

    def max(self, x: np.ndarray) -> np.ndarray:
        return x

    def any(self, x: np.ndarray) -> np.ndarray:
        return x

    def ordered_sum(self, x: np.ndarray) -> np.ndarray:
        stored = self.order is not None and x.shape[1] == len(self.order)  # (a centralised learner: one row)
        return ordered_sum(x[:, self.order] if stored else x)

    def consensus(self, W: np.ndarray) -> np.ndarray:
        """The consensus error (B,) of the agents' estimates W (B, N, q) (`ordered_consensus_error`)."""
        return ordered_consensus_error(W, W.shape[1], self.ordered_sum)

    def init_channel(self, channel, seeds: int, seed: int):
        return channel.init(seeds, self.arcs, seed)

    def whole(self, x: np.ndarray, axis: int = 1) -> np.ndarray:
        return x

    def whole_arcs(self, x: np.ndarray, n_arcs: int) -> np.ndarray:
        return x

    def reported(self, x: np.ndarray) -> np.ndarray:
        return x

    def shard(self) -> dict:
        return {}


def reported(channel_state, layout):
    """A channel's state with the per-arc entries of the arcs whose receivers ``layout`` holds (what it saves)."""
    return channel_state._replace(**{name: layout.reported(x) for name, x in per_arc_fields(channel_state).items()})
