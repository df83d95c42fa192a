"""What each agent heard at one step, as the neighbour aggregates an algorithm's update uses."""

from __future__ import annotations

import numpy as np

from dgtd.channels.arcs import Arcs
from dgtd.samples import namespace


class Inbox:
    """The messages every agent heard at step k, for B seeds: a channel's `deliver` builds it.

    ``sent`` maps each message name to what every agent sent, (B, N, q); ``heard`` (B, 2E) says which arcs delivered
    (1) and which did not (0); ``received``, where a channel changes what arrives (a late or compressed copy), maps a
    name to the value each arc delivered, (B, 2E, q); by default an arc delivers what its sender sent. For agent i and
    a message x, with j -> i the arcs that delivered to i:

    - ``laplacian(x)``: sum_j (x_i - x_j), the neighbour sums of Algorithm 1 (section 7 of the paper), (L(k) x)_i
      (each term weighted by its arc's ``weights`` where the channel gives them);
    - ``metropolis(x)``: sum_j W_ij (x_i - x_j) with W_ij = 1 / (1 + max(d_i, d_j)), d_i the number of messages i
      heard: sum_j W_ij(k) x_j = x_i - metropolis(x)_i, a doubly stochastic mix when every link works both ways;
    - ``total(x)``: sum_j x_j, and ``count()``: d_i.

    x_i is what agent i itself sent at step k (its own current value). Where a channel puts agents to sleep,
    ``awake`` (B, N) says who is awake: an asleep agent does not update (the backends keep its state as it was).
    """

    def __init__(
        self,
        arcs: Arcs,
        sent: dict,
        heard: np.ndarray,
        received: dict | None = None,
        weights=None,
        awake=None,
        degrees=None,
    ):
        self.arcs, self.sent, self.received = arcs, sent, received or {}
        self.heard = namespace(heard).asarray(heard, dtype=np.float64)
        self.weights = weights  # (2E,) what ``laplacian`` weighs each arc's term by, where a channel reweighs
        self.awake = awake
        self.degrees = degrees  # (B, N) d_i, where the inbox holds only some agents' arcs (an MPI rank's)

    def _arrived(self, name: str) -> np.ndarray:
        """What each arc delivered of message ``name`` (B, 2E, q), whether or not it was heard."""
        if name in self.received:
            return self.received[name]
        return self.sent[name][:, self.arcs.src]

    def _differences(self, name: str, weights: np.ndarray) -> np.ndarray:
        """sum over the arcs into each agent of weight_a (x_i - x_j)."""
        x = self.sent[name]
        return self.arcs.into((x[:, self.arcs.dst] - self._arrived(name)) * weights[:, :, None])

    def count(self) -> np.ndarray:
        """d_i, (B, N): how many messages of each name agent i heard."""
        if self.degrees is not None:
            return self.degrees
        return self.arcs.into(self.heard[:, :, None])[:, :, 0]

    def laplacian(self, name: str) -> np.ndarray:
        """(L(k) x)_i = sum_j (x_i - x_j) over the messages i heard, (B, N, q); sum_j c_ij (x_i - x_j) where the
        channel weighs what each arc delivers (``weights``: `dgtd.channels.Lossy` with ``reweight``)."""
        return self._differences(name, self.heard if self.weights is None else self.heard * self.weights)

    def metropolis(self, name: str) -> np.ndarray:
        """sum_j W_ij (x_i - x_j), W_ij = 1 / (1 + max(d_i, d_j)) (Metropolis weights of the links heard), (B, N, q)."""
        d = self.count()
        weights = self.heard / (1.0 + namespace(d).maximum(d[:, self.arcs.dst], d[:, self.arcs.src]))
        return self._differences(name, weights)

    def total(self, name: str) -> np.ndarray:
        """sum_j x_j over the messages i heard, (B, N, q)."""
        return self.arcs.into(self._arrived(name) * self.heard[:, :, None])


class HeldRows:
    """What the agents ``local`` heard (a learning run's agents held in this process): an `Inbox` of every agent,
    its aggregates' rows ``local``, ``awake`` theirs."""

    def __init__(self, inbox: Inbox, local):
        self.inbox, self.local = inbox, local
        self.awake = None if inbox.awake is None else inbox.awake[:, local]

    def laplacian(self, name: str):
        return self.inbox.laplacian(name)[:, self.local]

    def metropolis(self, name: str):
        return self.inbox.metropolis(name)[:, self.local]
