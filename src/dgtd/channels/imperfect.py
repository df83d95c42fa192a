"""Late, asleep and compressed messages, over links that may also lose them (`dgtd.channels.Lossy`).

Each arc j -> i is up at a step when its edge is up and its message is not lost (`Lossy.arcs_up`: the same draws).
Over an arc up at step k:

- the sender j, if awake, sends its messages; they arrive ``delay`` >= d >= 0 steps later, d uniform per message
  (``delay`` = D);
- the receiver i, if awake, mixes with the newest copy of j's messages it holds (and with nothing from j before the
  first arrives): the inbox's neighbour aggregates (`Inbox`) read that copy, i's own term its own current value.

An agent is awake at a step with probability ``wake[i]``; asleep, it neither updates nor sends, and its neighbours
keep using the last they heard from it. A message may be compressed on its arc: ``top_k`` keeps its K largest
coordinates (by magnitude; the lower index first among equals), and ``bits`` = B < 64 quantises each coordinate by
stochastic rounding onto the 2^B points evenly spaced on [-s, s], s the largest magnitude, sent alongside (64 bits).
With ``error_feedback``, what the arc carries is the compressed difference between the sender's value and the copy
both ends hold, which each end adds to it (CHOCO-gossip's public copies, Koloskova et al. 2019): what is not sent
now is sent later.

Where the links lose nothing, every agent is awake, nothing is late and nothing compressed, an arc's copy is its
sender's current value and the inbox is `Lossy`'s. Each step draws from the seed's keyed streams (`dgtd.streams`):
one uniform per arc for the links (`Lossy`), and where asked one per agent (awake: u < wake_i), one per arc (delay:
d = floor(u (D + 1))), and one per arc and number sent (stochastic rounding), each keyed by its agent or arc.
docs/links.md derives where each leads: none of delay, sleep, stochastic rounding or error feedback moves a
method's fixed point.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, NamedTuple

import numpy as np

from dgtd.channels.arcs import Arcs
from dgtd.channels.base import BITS_PER_NUMBER
from dgtd.channels.inbox import Inbox
from dgtd.channels.lossy import Lossy, arc_uniforms
from dgtd.errors import DgtdInputError
from dgtd.streams import DELAY, ROUNDING, WAKE, singles, uniforms


class HeldState(NamedTuple):
    """`Imperfect`'s state, per seed: `dgtd.channels.lossy.LinkState`'s fields, and what the receivers hold (empty
    until the first step tells how many numbers a message has): ``copies`` (B, 2E, Q), what each arc's receiver holds
    of its sender's messages (the Q numbers of all its messages side by side); ``since`` (B, 2E), the step that copy
    was sent at (-1: nothing heard yet); the messages in flight, ``pending`` (B, 2E, D + 1, Q), each in slot (step it
    arrives) mod (D + 1), the newest sent of those arriving at one step, with the step it arrives at, ``due``, and
    was sent at, ``posted`` (B, 2E, D + 1; -1: none); and ``per_arc`` (B, 2E), how many times each arc delivered."""

    messages: np.ndarray
    bits: np.ndarray
    keys: np.ndarray
    step: np.ndarray
    links: np.ndarray
    copies: np.ndarray = np.zeros((0, 0, 0))
    since: np.ndarray = np.zeros((0, 0), np.int64)
    pending: np.ndarray = np.zeros((0, 0, 0, 0))
    due: np.ndarray = np.zeros((0, 0, 0), np.int64)
    posted: np.ndarray = np.zeros((0, 0, 0), np.int64)
    per_arc: np.ndarray = np.zeros((0, 0))


@dataclass(frozen=True, eq=False)
class Imperfect:
    """The links of ``lossy`` (its loss, bursts and reweighting) with late (``delay`` D >= 0 steps at most), asleep
    (``wake`` (N,): each agent's probability of being awake at a step; None: always) and compressed (``bits``,
    ``top_k``, ``error_feedback``) messages."""

    lossy: Lossy
    delay: int = 0
    wake: np.ndarray | None = None
    bits: int = BITS_PER_NUMBER
    top_k: int | None = None
    error_feedback: bool = False
    name: ClassVar[str] = "imperfect"
    draws: ClassVar[bool] = True
    holds: ClassVar[bool] = True

    def __post_init__(self):
        check_links(self.delay, self.wake, self.bits, self.top_k, self.error_feedback)

    # what the run loop, the fixed points and the kernels' loss draws read of the links
    loss = property(lambda self: self.lossy.loss)
    burst = property(lambda self: self.lossy.burst)
    reweight = property(lambda self: self.lossy.reweight)
    enter = property(lambda self: self.lossy.enter)
    arc_weights = property(lambda self: self.lossy.arc_weights)

    @property
    def compresses(self) -> bool:
        return self.bits < BITS_PER_NUMBER or self.top_k is not None

    @property
    def linear(self) -> bool:
        """Whether what a receiver holds is, in the mean, linear in what was sent: top-k without error feedback keeps
        the largest coordinates, a choice that depends on the values, and its fixed point is not computed."""
        return self.top_k is None or self.error_feedback

    def init(self, seeds: int, arcs: Arcs, seed: int = 0) -> HeldState:
        """`Lossy.init`'s state, the copies left empty until the first step tells how many numbers a message has."""
        return HeldState(**self.lossy.init(seeds, arcs, seed)._asdict())

    def deliver(self, state: HeldState, arcs: Arcs, sent: dict, up: np.ndarray | None):
        """(the step's `Inbox`, the new state) from what every agent sent (name -> (B, N, q)) and the edges up. The
        messages in flight (``pending``, ``due``, ``posted``) are updated in ``state``'s own arrays; a caller that
        keeps the old state passes a copy (`HeldState.copy`)."""
        x = np.concatenate(list(sent.values()), axis=-1)  # (B, N, Q): every message side by side
        B, N, Q = x.shape
        state = held(state, arcs.n_arcs, Q, self.delay)
        t = state.step  # (B,): the same step for every seed
        carried, links = self.lossy.arcs_up(state, arcs, up, B)
        keys, step = state.keys, int(t[0])
        awake = np.ones((B, N), bool)
        if self.wake is not None:
            agents = arcs.agent_ids
            awake = singles(keys[:, None], WAKE, step, agents) < arcs.of_agents(self.wake)
        if self.delay:
            u = arc_uniforms(keys, DELAY, step, arcs)
            late = np.minimum(np.floor(u * (self.delay + 1)).astype(np.int64), self.delay)
        rounding = None
        if self.bits < BITS_PER_NUMBER:  # an arc's numbers 2j and 2j + 1 from its call j (entity: its side)
            link = arcs.link_keys(keys)[:, :, None]
            u0, u1 = uniforms(link, ROUNDING, step, arcs.side[:, None], np.arange((Q + 1) // 2))
            rounding = np.stack([u0, u1], axis=-1).reshape(B, arcs.n_arcs, -1)[:, :, :Q]
        sends = carried & awake[:, arcs.src]
        value = x[:, arcs.src]
        copies, since = state.copies.copy(), state.since.copy()
        if self.compresses:
            base = copies if self.error_feedback else np.zeros_like(value)
            value = base + self.compress(value - base, rounding, [m.shape[-1] for m in sent.values()])
        pending, due, posted = state.pending, state.due, state.posted
        if not self.delay:
            copies[sends] = value[sends]
            since = np.where(sends, t[:, None], since)
        else:  # in place: copying the D + 1 slots each step made a step cost O(D)
            arrives = t[:, None] + late
            b, a = np.nonzero(sends)
            s = arrives[b, a] % (self.delay + 1)  # one slot per arrival step: D + 1 cover those in flight
            pending[b, a, s] = value[b, a]  # the newest sent of those arriving together: only it can be read
            due[b, a, s], posted[b, a, s] = arrives[b, a], t[b]
            now = step % (self.delay + 1)
            arrived = due[:, :, now] == t[:, None]
            newer = arrived & (posted[:, :, now] > since)
            copies[newer] = pending[:, :, now][newer]
            since = np.where(newer, posted[:, :, now], since)
            due[:, :, now] = np.where(arrived, -1, due[:, :, now])
            posted[:, :, now] = np.where(arrived, -1, posted[:, :, now])
        heard = (carried & (since >= 0)).astype(np.float64)
        received, start = {}, 0
        for name, m in sent.items():
            received[name] = copies[:, :, start : start + m.shape[-1]]
            start += m.shape[-1]
        delivered = sends.sum(axis=1).astype(np.float64)
        bits = sum(self.vector_bits(m.shape[-1]) for m in sent.values())
        weights = arcs.of_arcs(self.arc_weights) if self.reweight else None
        inbox = Inbox(arcs, sent, heard, received, weights, awake if self.wake is not None else None)
        return inbox, HeldState(
            state.messages + delivered * len(sent),
            state.bits + delivered * bits,
            keys,
            t + 1,
            links,
            copies,
            since,
            pending,
            due,
            posted,
            state.per_arc + sends,
        )

    def share(self, arc_ids: np.ndarray, agents: np.ndarray) -> Imperfect:
        """Each of the arcs ``arc_ids``' own links and each of ``agents``' own probability of being awake."""
        wake = None if self.wake is None else self.wake[agents]
        lossy = self.lossy.share(arc_ids, agents)
        return Imperfect(lossy, self.delay, wake, self.bits, self.top_k, self.error_feedback)

    def mean_mixing(self, network, arcs: Arcs, mixing: str):
        """The links' (`Lossy.mean_mixing`): neither delay, sleep nor compression moves it (docs/links.md)."""
        return self.lossy.mean_mixing(network, arcs, mixing)

    def compress(self, v: np.ndarray, rounding: np.ndarray | None, widths: list[int]) -> np.ndarray:
        """What an arc carries of v (B, 2E, Q), message by message (``widths``: each one's numbers): its top-k
        coordinates, each rounded stochastically onto B bits with ``rounding``'s uniforms (B, 2E, Q)."""
        out, start = np.empty_like(v), 0
        for q in widths:
            part = slice(start, start + q)
            out[..., part] = compress_vector(v[..., part], None if rounding is None else rounding[..., part], self)
            start += q
        return out

    def vector_bits(self, q: int) -> int:
        """Bits an arc carries for one message of q numbers: each number kept (the K largest, with its index of
        ceil(log2 q) bits, under top-k) in B bits, and the scale (64 bits) where rounded."""
        kept = q if self.top_k is None else min(self.top_k, q)
        index = 0 if kept == q else int(np.ceil(np.log2(q)))
        scale = BITS_PER_NUMBER if self.bits < BITS_PER_NUMBER else 0
        return kept * (min(self.bits, BITS_PER_NUMBER) + index) + scale

    def describe(self) -> str:
        parts = [self.lossy.describe()] if self.lossy.loss.any() or self.lossy.reweight else []
        if self.delay:
            parts.append(f"messages up to {self.delay} steps late")
        if self.wake is not None:
            lo, hi = float(self.wake.min()), float(self.wake.max())
            parts.append(f"agents awake w.p. {lo:g}" if lo == hi else f"agents awake w.p. in [{lo:g}, {hi:g}]")
        if self.top_k is not None:
            parts.append(f"top-{self.top_k} coordinates")
        if self.bits < BITS_PER_NUMBER:
            parts.append(f"{self.bits} bits a number")
        if self.error_feedback:
            parts.append("with error feedback")
        return ", ".join(parts) or "every message delivered"


def compress_vector(v: np.ndarray, u: np.ndarray | None, channel: Imperfect) -> np.ndarray:
    """One message (..., q) as its arc carries it: top-k, then stochastic rounding with the uniforms u (..., q)."""
    q = v.shape[-1]
    if channel.top_k is not None and channel.top_k < q:
        order = np.argsort(-np.abs(v), axis=-1, kind="stable")  # the lower index first among equal magnitudes
        keep = np.zeros(v.shape, bool)
        np.put_along_axis(keep, order[..., : channel.top_k], True, axis=-1)
        v = np.where(keep, v, 0.0)
    else:
        keep = np.ones(v.shape, bool)
    if u is None:
        return v
    levels = 2.0**channel.bits - 1.0
    s = np.abs(v).max(axis=-1, keepdims=True)
    safe = np.where(s > 0, s, 1.0)
    pos = (v + safe) / (2.0 * safe) * levels
    k = np.floor(pos)
    k = k + (u < pos - k)
    rounded = k * (2.0 * safe / levels) - safe
    return np.where(keep & (s > 0), rounded, 0.0)


def held(state: HeldState, n_arcs: int, Q: int, delay: int) -> HeldState:
    """``state`` with the receivers' copies made (nothing heard yet) where it has none."""
    B = state.messages.shape[0]
    if state.copies.shape == (B, n_arcs, Q):
        return state
    slots = delay + 1 if delay else 0
    return state._replace(
        copies=np.zeros((B, n_arcs, Q)),
        since=np.full((B, n_arcs), -1, np.int64),
        pending=np.zeros((B, n_arcs, slots, Q)),
        due=np.full((B, n_arcs, slots), -1, np.int64),
        posted=np.full((B, n_arcs, slots), -1, np.int64),
        step=np.zeros(B, np.int64),
        per_arc=np.zeros((B, n_arcs)),
    )


def check_links(delay, wake, bits, top_k, error_feedback) -> None:
    """One line for link parameters that make no sense."""
    if not (isinstance(delay, int | np.integer) and 0 <= delay <= 10_000):
        raise DgtdInputError(f"delay: the most steps a message is late, a whole number in [0, 10000]; got {delay}")
    if wake is not None:
        w = np.asarray(wake, dtype=np.float64)
        bad = ~np.isfinite(w) | (w <= 0) | (w > 1)
        if bad.any():
            raise DgtdInputError(f"wake: the probability that an agent is awake must lie in (0, 1], got {w[bad][0]:g}")
    if not (isinstance(bits, int | np.integer) and 1 <= bits <= BITS_PER_NUMBER):
        raise DgtdInputError(f"bits: the bits a number is sent in, a whole number in [1, 64]; got {bits}")
    if top_k is not None and not (isinstance(top_k, int | np.integer) and top_k >= 1):
        raise DgtdInputError(f"top_k: the coordinates a message keeps, a whole number >= 1; got {top_k}")
    if error_feedback and bits >= BITS_PER_NUMBER and top_k is None:
        raise DgtdInputError("error feedback corrects compressed messages; give --bits B (< 64) or --top-k K too")
    if error_feedback and delay:
        raise DgtdInputError(
            "error feedback with late messages is not supported: leave out --delay or --error-feedback"
        )


def wake_per_agent(wake, n_agents: int) -> np.ndarray | None:
    """Each agent's probability of being awake (N,) from one value or one per agent (a list or 'q1,q2,...')."""
    if wake is None:
        return None
    try:
        values = [float(x) for x in wake.split(",")] if isinstance(wake, str) else wake
        w = np.atleast_1d(np.asarray(values, dtype=np.float64))
    except ValueError:
        raise DgtdInputError(f"wake: give a probability or one per agent, comma-separated; got {wake!r}") from None
    if w.size not in (1, n_agents):
        raise DgtdInputError(f"wake: give one probability, or one per agent ({n_agents} here); got {w.size} values")
    check_links(0, w, BITS_PER_NUMBER, None, False)
    w = np.broadcast_to(w, (n_agents,)).copy()
    return None if (w == 1.0).all() else w
