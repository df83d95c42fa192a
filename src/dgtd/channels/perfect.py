"""The perfect channel: what the paper assumes (section 2.3), and dgtd's default."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, NamedTuple

import numpy as np

from dgtd.channels.arcs import Arcs
from dgtd.channels.inbox import Inbox

BITS_PER_NUMBER = 64  # a message's coordinates are float64


class ChannelState(NamedTuple):
    """What a channel carries from step to step, per seed: the counts of messages and bits it delivered (B,), the
    seed's key (B,) where the channel draws events (`dgtd.streams`; empty where it draws none), each arc's state
    where links have one (B, 2E: 1 while a bursty link is in its losing state; else B, 0), and the step ``step`` (B,)
    where it draws events.

    A channel whose receivers keep copies of what they heard (`dgtd.channels.Imperfect`: late, asleep or compressed
    messages) also carries, else holds empty arrays: ``copies`` (B, 2E, Q), what each arc's receiver holds of its
    sender's messages (the Q numbers of all its messages side by side); ``since`` (B, 2E), the step that copy was
    sent at (-1: nothing heard yet); the messages in flight, ``pending`` (B, 2E, D + 1, Q), each in slot (step it
    arrives) mod (D + 1), the newest sent of those arriving at one step, with the step it arrives at, ``due``, and
    was sent at, ``posted`` (B, 2E, D + 1; -1: none); and
    ``per_arc`` (B, 2E), how many times each arc delivered."""

    messages: np.ndarray
    bits: np.ndarray
    keys: np.ndarray = np.zeros(0, np.uint64)
    links: np.ndarray = np.zeros((0, 0), np.uint8)
    copies: np.ndarray = np.zeros((0, 0, 0))
    since: np.ndarray = np.zeros((0, 0), np.int64)
    pending: np.ndarray = np.zeros((0, 0, 0, 0))
    due: np.ndarray = np.zeros((0, 0, 0), np.int64)
    posted: np.ndarray = np.zeros((0, 0, 0), np.int64)
    step: np.ndarray = np.zeros(0, np.int64)
    per_arc: np.ndarray = np.zeros((0, 0))

    def copy(self) -> ChannelState:
        """A state of its own: `dgtd.channels.Imperfect.deliver` updates the messages in flight in place."""
        return ChannelState(*(np.array(x) for x in self))


# the fields of a channel's state that hold one entry per arc (their axis 1)
PER_ARC = ("links", "copies", "since", "pending", "due", "posted", "per_arc")


def per_arc_fields(state) -> dict:
    """The per-arc fields (`PER_ARC`) a channel's state holds (B, arcs, ...), some perhaps of size 0 (no slots for
    late messages); those it does not are empty placeholders ((0, ...) or (B, 0))."""
    B = state.messages.shape[0]
    return {name: x for name in PER_ARC if (x := getattr(state, name)).ndim >= 2 and x.shape[0] == B and x.shape[1]}


@dataclass(frozen=True)
class Perfect:
    """Every link up at step k carries every message both ways, at once and exactly: agent i hears x_j(k) from each
    neighbour j whose link is up at step k, and nothing else."""

    name: ClassVar[str] = "perfect"

    def init(self, seeds: int, arcs: Arcs, seed: int = 0) -> ChannelState:
        return ChannelState(np.zeros(seeds), np.zeros(seeds), np.zeros(0, np.uint64), np.zeros((seeds, 0), np.uint8))

    def deliver(self, state: ChannelState, arcs: Arcs, sent: dict, up: np.ndarray | None):
        """(the step's `Inbox`, the new state) from what every agent sent (name -> (B, N, q)) and the edges up (B, E)
        (None: every edge)."""
        inbox = self.inbox(arcs, sent, up)
        arrived = inbox.heard.sum(axis=1)
        numbers = sum(x.shape[-1] for x in sent.values())  # coordinates per arc, all messages together
        return inbox, ChannelState(
            state.messages + arrived * len(sent),
            state.bits + arrived * numbers * BITS_PER_NUMBER,
            state.keys,
            state.links,
        )

    def describe(self) -> str:
        return "every message delivered"

    def inbox(self, arcs: Arcs, sent: dict, up: np.ndarray | None = None) -> Inbox:
        """What every agent hears of ``sent`` (name -> (B, N, q)) over the edges up (B, E) (None: every edge)."""
        B = next(iter(sent.values())).shape[0] if sent else (1 if up is None else up.shape[0])
        heard = arcs.up(up, B).astype(np.float64)
        return Inbox(arcs, sent, heard)
