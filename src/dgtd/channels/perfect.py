"""The perfect channel: what the paper assumes (section 2.3), and dgtd's default."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, NamedTuple

import numpy as np

from dgtd.channels.arcs import Arcs
from dgtd.channels.base import counted
from dgtd.channels.inbox import Inbox


class Counts(NamedTuple):
    """`Perfect`'s state, per seed: the counts of messages and bits it delivered (B,)."""

    messages: np.ndarray
    bits: np.ndarray


@dataclass(frozen=True)
class Perfect:
    """Every link up at step k carries every message both ways, at once and exactly: agent i hears x_j(k) from each
    neighbour j whose link is up at step k, and nothing else."""

    name: ClassVar[str] = "perfect"
    draws: ClassVar[bool] = False
    holds: ClassVar[bool] = False

    def init(self, seeds: int, arcs: Arcs, seed: int = 0) -> Counts:
        return Counts(np.zeros(seeds), np.zeros(seeds))

    def deliver(self, state: Counts, arcs: Arcs, sent: dict, up: np.ndarray | None):
        """(the step's `Inbox`, the new state) from what every agent sent (name -> (B, N, q)) and the edges up (B, E)
        (None: every edge)."""
        inbox = self.inbox(arcs, sent, up)
        numbers = sum(x.shape[-1] for x in sent.values())  # coordinates per arc, all messages together
        return inbox, counted(state, inbox.heard.sum(axis=1), len(sent), numbers)

    def share(self, arc_ids: np.ndarray, agents: np.ndarray) -> Perfect:
        return self

    def mean_mixing(self, network, arcs: Arcs, mixing: str):
        """The network's mean Laplacian (each link up both ways at once): the symmetric mixing of either kind has
        the same null vectors."""
        return network.mean_laplacian()

    def describe(self) -> str:
        return "every message delivered"

    def inbox(self, arcs: Arcs, sent: dict, up: np.ndarray | None = None) -> Inbox:
        """What every agent hears of ``sent`` (name -> (B, N, q)) over the edges up (B, E) (None: every edge)."""
        B = next(iter(sent.values())).shape[0] if sent else (1 if up is None else up.shape[0])
        heard = arcs.up(up, B).astype(np.float64)
        return Inbox(arcs, sent, heard)


def mean_metropolis(network, sparse: bool = False):
    """E[I - W(k)] (N, N; scipy CSR with ``sparse``) of the Metropolis mixing over the network's own links, every
    message delivered (exact: `dgtd.channels.lossy.mean_metropolis` at loss 0)."""
    from dgtd.channels.lossy import mean_metropolis as over_lossy_links

    arcs = Arcs.of(network.base.edges, network.n_nodes)
    return over_lossy_links(network, np.zeros(arcs.n_arcs), arcs, sparse)
