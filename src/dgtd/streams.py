"""Keyed random streams: every random number of a run is a pure function of (seed, purpose, entity, step, index).

The generator is Philox-4x32-10 (Salmon, Moraes, Dror and Shaw, "Parallel random numbers: as easy as 1, 2, 3",
SC 2011), a counter-based generator: ten rounds of a keyed bijection of a 128-bit counter, each round two 32 x 32 ->
64-bit multiplies. Chosen over Threefry-2x32-20 because it gives 128 bits (two doubles) per call in half the
rounds, its multiplies are native on every CPU and GPU (no 64-bit arithmetic needed, as JAX on a GPU prefers), and
it passes BigCrush with margin (7 rounds already do). Its published known-answer values (Random123's kat_vectors)
are checked in the tests.

A seed's numbers are laid out so that anyone can draw their own, in any order, on any rank or device:

- the key (64 bits) is the seed's: seed k of base seed s has the key `seed_key`(s, k), the first two words of
  Philox(counter = (k mod 2^32, k div 2^32, 0, 0), key = (s mod 2^32, s div 2^32));
- the counter (128 bits) is (step mod 2^32, step div 2^32, entity, purpose * 2^24 + index): the step of the run,
  the entity the number is for (an agent, an observation), the purpose (`PURPOSES`) and the index of the call among
  those of one (purpose, entity, step) (a message of many numbers);
- a link's numbers are keyed by the agents it joins, not by its place in any list, so that whoever holds the link
  (either end; a rank that made only its part of the graph) draws them: the link {i, j}, i < j, has the key
  `link_keys` (its seed's key, i, j), the first two words of Philox(counter = (i, j, 0, LINK * 2^24), key = the
  seed's key), and its numbers the counter (step mod 2^32, step div 2^32, side, purpose * 2^24 + index) under that
  key; of its two arcs (a message's way), the one into i (the smaller id) is side 0 and the one into j side 1, and
  where each arc needs one number a step, the arc into i takes u0 of side 0's call and the arc into j its u1;
- a call gives two doubles in [0, 1) of 53 bits each: words (x1 x0) and (x3 x2) read as 64-bit integers, their top
  53 bits times 2^-53 (`uniforms`). Where an agent needs one number a step (its reward noise, wake or action),
  entities 2j and 2j + 1 share call j (entity j), the first taking u0 and the second u1 (`singles`): half
  the calls, and still a pure function of the entity.

`philox4x32` is written once in plain arithmetic on unsigned 64-bit values: NumPy runs it on arrays (the readable
definition) and numba compiles the same function for the kernels (`dgtd.backends.compiled.rng`), bit for bit equal.
"""

from __future__ import annotations

import numpy as np

_M0, _M1 = np.uint64(0xD2511F53), np.uint64(0xCD9E8D57)  # Philox-4x32 multipliers
_W0, _W1 = np.uint64(0x9E3779B9), np.uint64(0xBB67AE85)  # its key schedule's Weyl increments
_LOW = np.uint64(0xFFFFFFFF)
_32 = np.uint64(32)
_11 = np.uint64(11)
_24 = np.uint64(24)
_TO_UNIT = 1.0 / 9007199254740992.0  # 2^-53
ROUNDS = 10

# What a number is for: the counter's purpose byte. Never reuse or renumber one: a seed's numbers would change.
SEED = 0  # deriving a seed's key (its own key space: the base seed's)
SHARED_STATE = 1  # the shared trajectory's (s, a, s') at a step (entity 0): u for s ~ d or a restart, u for (a, s')
AGENT_STATE = 2  # agent i's own trajectory's (s, a, s') at a step (entity i), as SHARED_STATE
SHARED_START = 3  # the shared trajectory's first state s_0 ~ d (step 0, entity 0)
AGENT_START = 4  # agent i's first state s_0 ~ d (step 0, entity i)
REWARD = 5  # agent i's reward noise at a step (paired: `singles`)
EDGE_UP = 6  # a link being up at a step (u0 under its key: both ends draw the same number)
ARC_LOSS = 7  # the losses (or burst moves) of a link's two arcs at a step: u0 the arc into i's, u1 the arc into j's
ARC_BURST_START = 8  # the first states of the arcs' burst chains (step 0), as ARC_LOSS
WAKE = 9  # agent i being awake at a step (paired: `singles`)
DELAY = 10  # how late the messages on an arc are at a step, as ARC_LOSS
ROUNDING = 11  # the stochastic rounding of an arc's numbers at a step (entity: its side): index j gives 2j and 2j + 1
ORDER = 12  # the order of a recording's rows for a seed (step 0, entity = row)
SIMULATOR = 13  # the seeds of a simulator's episodes and its policy's generator (entity = episode, step 0)
ACTION = 14  # agent i's action drawn from its own policy at a step, while it learns (paired: `singles`)
GRAPH = 15  # a keyed random graph's chunk (entity: the chunk, or an agent's links; step: the number's place)
DISCOUNTED_RESTART = 16  # a discounted visitation chain's restart at a sample (entity 0: u to restart, u for s ~ start)
PROBLEM = 17  # a generated problem's numbers of agent i (entity i; step: the number's place)
HOOD_LOSS = 18  # what agent i hears from the member in slot ``index`` of its kappa-hop neighbourhood at a step being
# lost (entity i): u0 for its state and action, u1 for its truncated value
LINK = 19  # a link's key (`link_keys`): its seed's key's numbers at counter (i, j, 0, LINK * 2^24)

PURPOSES = {
    "seed": SEED,
    "shared-state": SHARED_STATE,
    "agent-state": AGENT_STATE,
    "shared-start": SHARED_START,
    "agent-start": AGENT_START,
    "reward": REWARD,
    "edge-up": EDGE_UP,
    "arc-loss": ARC_LOSS,
    "arc-burst-start": ARC_BURST_START,
    "wake": WAKE,
    "delay": DELAY,
    "rounding": ROUNDING,
    "order": ORDER,
    "simulator": SIMULATOR,
    "action": ACTION,
    "graph": GRAPH,
    "discounted-restart": DISCOUNTED_RESTART,
    "problem": PROBLEM,
    "hood-loss": HOOD_LOSS,
    "link": LINK,
}


def philox4x32(c0, c1, c2, c3, k0, k1):
    """Philox-4x32-10 of counter (c0, c1, c2, c3) under key (k0, k1): four 32-bit words, each held in a uint64.

    Random123's round: (c0, c1, c2, c3) <- (hi(M1 c2) ^ c1 ^ k0, lo(M1 c2), hi(M0 c0) ^ c3 ^ k1, lo(M0 c0)), the key
    bumped by the Weyl increments between rounds. Plain arithmetic on uint64 scalars or arrays (NumPy or numba)."""
    for _ in range(ROUNDS):
        p0 = _M0 * c0
        p1 = _M1 * c2
        c0, c1, c2, c3 = (p1 >> _32) ^ c1 ^ k0, p1 & _LOW, (p0 >> _32) ^ c3 ^ k1, p0 & _LOW
        k0 = (k0 + _W0) & _LOW
        k1 = (k1 + _W1) & _LOW
    return c0, c1, c2, c3


def uniforms(key, purpose, step, entity, index=0):
    """The two doubles in [0, 1) for (``key``, ``purpose``, ``step``, ``entity``, ``index``): ``key`` seeds' 64-bit
    keys (`seed_key`), the rest whole numbers (purpose < 256, index < 2^24, entity < 2^32, step < 2^64); arrays are
    broadcast against each other as given (callers shape them). Returns two float64 arrays of the broadcast shape."""
    as_u64 = lambda x: np.asarray(x, dtype=np.uint64)  # noqa: E731
    key, step, entity, index = as_u64(key), as_u64(step), as_u64(entity), as_u64(index)
    tag = (np.uint64(purpose) << _24) | index
    x0, x1, x2, x3 = philox4x32(step & _LOW, step >> _32, entity, tag, key & _LOW, key >> _32)
    u0 = (((x1 << _32) | x0) >> _11).astype(np.int64).astype(np.float64) * _TO_UNIT
    u1 = (((x3 << _32) | x2) >> _11).astype(np.int64).astype(np.float64) * _TO_UNIT
    return u0, u1


def singles(key, purpose, step, ids):
    """One uniform for each entity of ``ids`` (whole numbers): entities 2j and 2j + 1 take the two doubles of the call
    of entity j. Broadcast as `uniforms`, ``ids`` along the last axis; the numbers of a range of ids (a rank's
    agents) take one call for each pair of them."""
    ids = np.asarray(ids, dtype=np.int64)
    n = ids.shape[-1]
    if ids.ndim == 1 and n and (n == 1 or np.all(np.diff(ids) == 1)):  # first .. first + n - 1: each call once
        first = int(ids[0])
        u0, u1 = uniforms(key, purpose, step, np.arange(first >> 1, ((first + n - 1) >> 1) + 1))
        both = np.stack([u0, u1], axis=-1).reshape(u0.shape[:-1] + (2 * u0.shape[-1],))
        return both[..., first & 1 : (first & 1) + n]
    u0, u1 = uniforms(key, purpose, step, ids >> 1)
    return np.where(ids & 1 == 0, u0, u1)


def seed_key(seed: int, k: int) -> int:
    """The 64-bit key of seed k of base seed ``seed`` (both whole numbers in [0, 2^64))."""
    seed, k = int(seed), int(k)
    if not (0 <= seed < 1 << 64 and 0 <= k < 1 << 64):
        raise ValueError(f"a seed is a whole number in [0, 2^64), got {seed} and {k}")
    u = np.uint64
    x0, x1, _, _ = philox4x32(u(k & 0xFFFFFFFF), u(k >> 32), u(0), u(SEED << 24), u(seed & 0xFFFFFFFF), u(seed >> 32))
    return int(x0) | (int(x1) << 32)


def seed_keys(seed: int, seed_ids) -> np.ndarray:
    """The keys (B,) uint64 of seeds ``seed_ids`` of base seed ``seed``."""
    return np.array([seed_key(seed, k) for k in seed_ids], dtype=np.uint64).reshape(-1)


def link_keys(keys, i, j) -> np.ndarray:
    """The 64-bit keys of the links joining agents ``i`` and ``j`` (whole numbers < 2^32, ids in the whole network,
    either end first) under seeds' keys ``keys``, broadcast against each other (keys (B, 1) and agents (E,) give
    (B, E))."""
    key = np.asarray(keys, dtype=np.uint64)
    i, j = np.asarray(i, dtype=np.int64), np.asarray(j, dtype=np.int64)
    lo, hi = np.minimum(i, j).astype(np.uint64), np.maximum(i, j).astype(np.uint64)
    x0, x1, _, _ = philox4x32(lo, hi, np.uint64(0), np.uint64(LINK << 24), key & _LOW, key >> _32)
    return x0 | (x1 << _32)


def arc_side(senders, receivers) -> np.ndarray:
    """Each arc's side of its link (0: into the smaller id, 1: into the larger; `link_keys`), as uint8."""
    return (np.asarray(receivers) > np.asarray(senders)).astype(np.uint8)


def edge_uniforms(keys, steps, edges) -> np.ndarray:
    """One uniform (..., B, E) for each link of ``edges`` (E, 2) of agents at each of ``steps`` (shaped to broadcast
    against (B, E), as (T, 1, 1)), seeds' keys ``keys`` (B,): whether it is up (EDGE_UP)."""
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    keys = link_keys(np.asarray(keys, dtype=np.uint64).reshape(-1, 1), edges[:, 0], edges[:, 1])
    return uniforms(keys, EDGE_UP, steps, 0)[0]


def entity_seed(key: int, purpose: int, entity: int, step: int = 0) -> int:
    """A 64-bit integer for seeding another library's generator (a simulator's ``reset(seed=...)``, the policy's
    ``np.random.Generator``) from (key, purpose, entity, step): the 53-bit halves of one call joined."""
    u0, u1 = uniforms(np.uint64(key), purpose, step, entity)
    return (int(u0 * 2.0**53) << 11) ^ int(u1 * 2.0**53)
