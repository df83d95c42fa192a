"""The compiled twin of `dgtd.channels.Imperfect`: late, asleep and compressed messages, line for line.

The driver's kernel for such a channel (`dgtd.backends.compiled.driver._seeds_held`) keeps each arc's copy of its
sender's messages in rows N + a of the step's message buffer, and reads a neighbour's messages there: the graph's
neighbour of arc a is row N + a (`held_graph`). So the inbox's aggregates (`dgtd.backends.compiled.channel`) read the
copies as they read the messages themselves on a perfect channel, and every algorithm's step runs unchanged.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from dgtd.backends.compiled.rng import keyed_pair
from dgtd.streams import DELAY, ROUNDING, WAKE


class Links(NamedTuple):
    """What `carry` reads of the channel: ``wake`` (N,) each agent's probability of being awake (empty: always),
    ``delay`` D, ``bits`` B, ``top_k`` K (0: none), ``feedback`` (1 with error feedback), ``width`` q (the numbers
    of each message), each arc's sender as an agent (``src``) and as a storage row (``src_row``), the ids of the
    agents in the whole network and the arcs counted (`dgtd.backends.compiled.sampling.entity_ids`), and each edge's
    key (B, E) and arc's side (2E,), which its delays and roundings are drawn by (`sampling.link_keys_of`)."""

    wake: np.ndarray
    delay: int
    bits: int
    top_k: int
    feedback: int
    width: int
    src: np.ndarray
    src_row: np.ndarray
    agent_ids: np.ndarray
    counted: np.ndarray
    edge_keys: np.ndarray
    arc_side: np.ndarray


class Held(NamedTuple):
    """The channel's state per seed (`dgtd.channels.HeldState`'s fields of the same names) and scratch."""

    copies: np.ndarray  # (B, 2E, Q)
    since: np.ndarray  # (B, 2E)
    pending: np.ndarray  # (B, 2E, D + 1, Q)
    due: np.ndarray  # (B, 2E, D + 1)
    posted: np.ndarray  # (B, 2E, D + 1)
    step: np.ndarray  # (B,)
    per_arc: np.ndarray  # (B, 2E)
    delivered: np.ndarray  # (B,): how many arcs carried a message in the block


@njit(cache=True)
def carry(links, held, b, t, rng, up_t, sent, N, scratch):
    """Step t of seed b (`dgtd.channels.Imperfect.deliver`): who is awake (into ``awake`` (N,)), what each arc carries
    and each receiver holds, written into the buffer rows N + a of ``sent``, and in up_t[0] the arcs heard (carried,
    and a copy held); returns how many arcs carried a message. ``scratch``: (awake (N,), late (2E,), rounding
    (2E, Q), value (Q,), chosen (Q,)), ``awake`` read by the driver after."""
    awake, late, rounding, value, chosen = scratch
    A, D = up_t.shape[1], links.delay
    M, q = sent.shape[0], links.width
    key = rng[b, 0]  # the seed's key (`dgtd.streams`): each number keyed by its agent or arc and the step t
    _draw_awake(links, key, t, N, awake)
    _draw_delays_and_rounding(links, links.edge_keys[b], t, A, D, held.copies.shape[2], late, rounding)
    now = t % (D + 1)
    n = 0
    for a in range(A):
        if up_t[0, a] and awake[links.src[a]]:
            n += 1 if links.counted.shape[0] == 0 else links.counted[a]
            _send(links, held, b, a, t, sent, value, rounding, chosen, late[a], M, q)
        if D > 0 and held.due[b, a, now] == t:  # what arrives now
            _arrive(held, b, a, now)
        up_t[0, a] = up_t[0, a] and held.since[b, a] >= 0
        for m in range(M):
            for f in range(q):
                sent[m, b, N + a, f] = held.copies[b, a, m * q + f]
    return n


@njit(cache=True, inline="always")
def _draw_awake(links, key, t, N, awake):
    """Who is awake at step t (every agent where no wake probability is set)."""
    u_even = u_odd = 0.0
    pair = -1
    for k in range(N):
        awake[k] = True
        if links.wake.shape[0] > 0:  # agents 2j and 2j + 1 share call j (`dgtd.streams.singles`)
            agent = k if links.agent_ids.shape[0] == 0 else links.agent_ids[k]
            if agent >> 1 != pair:
                pair = agent >> 1
                u_even, u_odd = keyed_pair(key, WAKE, t, pair, 0)
            awake[k] = (u_even if agent & 1 == 0 else u_odd) < links.wake[k]


@njit(cache=True, inline="always")
def _draw_delays_and_rounding(links, keys, t, A, D, Q, late, rounding):
    """Each arc's delay at step t (uniform in 0..D) and the uniforms of its stochastic rounding, where drawn, by its
    link's key (``keys`` (E,)) and its side (`dgtd.streams`)."""
    side = links.arc_side
    if D > 0:
        for e in range(A // 2):
            u0, u1 = keyed_pair(keys[e], DELAY, t, 0, 0)
            for a in range(2 * e, 2 * e + 2):
                late[a] = min(np.int64(np.floor((u0 if side[a] == 0 else u1) * (D + 1))), D)
    if links.bits < 64:
        for a in range(A):
            for f in range(0, Q, 2):
                u0, u1 = keyed_pair(keys[a >> 1], ROUNDING, t, side[a], f // 2)
                rounding[a, f] = u0
                if f + 1 < Q:
                    rounding[a, f + 1] = u1


@njit(cache=True, inline="always")
def _send(links, held, b, a, t, sent, value, rounding, chosen, late, M, q):
    """Arc a carries its sender's messages at step t: compressed where the links compress, into the receiver's copy
    at once or into the slot of the step it arrives at (one slot per arrival step, the newest sent kept)."""
    Q, D = held.copies.shape[2], links.delay
    held.per_arc[b, a] += 1.0
    j = links.src_row[a]
    for m in range(M):
        for f in range(q):
            value[m * q + f] = sent[m, b, j, f]
    if links.bits < 64 or links.top_k > 0:
        for m in range(M):
            compress(links, held, b, a, m * q, value, rounding, chosen)
    if D == 0:
        for f in range(Q):
            held.copies[b, a, f] = value[f]
        held.since[b, a] = t
        return
    s = (t + late) % (D + 1)
    for f in range(Q):
        held.pending[b, a, s, f] = value[f]
    held.due[b, a, s] = t + late
    held.posted[b, a, s] = t


@njit(cache=True, inline="always")
def _arrive(held, b, a, now):
    """The message due on arc a now replaces the receiver's copy, unless a newer one arrived first."""
    if held.posted[b, a, now] > held.since[b, a]:
        for f in range(held.copies.shape[2]):
            held.copies[b, a, f] = held.pending[b, a, now, f]
        held.since[b, a] = held.posted[b, a, now]
    held.due[b, a, now] = -1
    held.posted[b, a, now] = -1


@njit(cache=True, inline="always")
def compress(links, held, b, a, start, value, rounding, chosen):
    """value[start : start + q] as its arc carries it (`dgtd.channels.imperfect.compress_vector`): with error
    feedback, the copy plus the compressed difference from it."""
    q = links.width
    if links.feedback:
        for f in range(q):
            value[start + f] -= held.copies[b, a, start + f]
    _choose_top_k(links.top_k, value, start, chosen, q)
    if links.bits < 64:
        _round(links.bits, value, start, rounding, a, chosen, q)
    if links.feedback:
        for f in range(q):
            value[start + f] += held.copies[b, a, start + f]


@njit(cache=True, inline="always")
def _choose_top_k(top_k, value, start, chosen, q):
    """chosen[f]: whether coordinate f is kept, the K largest magnitudes (the lower index first among equals), or
    every one; the rest zeroed."""
    for f in range(q):
        chosen[f] = not 0 < top_k < q
    if not 0 < top_k < q:
        return
    for _ in range(top_k):
        best, at = -1.0, 0
        for f in range(q):
            if not chosen[f] and abs(value[start + f]) > best:
                best, at = abs(value[start + f]), f
        chosen[at] = True
    for f in range(q):
        if not chosen[f]:
            value[start + f] = 0.0


@njit(cache=True, inline="always")
def _round(bits, value, start, rounding, a, chosen, q):
    """Stochastic rounding to 2^bits - 1 levels over [-s, s], s the largest magnitude, by arc a's uniforms (indexed
    in place: a row view would cost a reference count)."""
    levels = 2.0**bits - 1.0
    s = 0.0
    for f in range(q):
        s = max(s, abs(value[start + f]))
    safe = s if s > 0 else 1.0
    for f in range(q):
        pos = (value[start + f] + safe) / (2.0 * safe) * levels
        k = np.floor(pos)
        k = k + (1.0 if rounding[a, start + f] < pos - k else 0.0)
        rounded = k * (2.0 * safe / levels) - safe
        value[start + f] = rounded if chosen[f] and s > 0 else 0.0
