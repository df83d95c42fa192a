"""Wireless access: users on a grid of cells send packets with deadlines to access points, and two users that send to
one access point at one step both fail (Qu, Wierman and Li, "Scalable reinforcement learning of localized policies
for multi-agent networked systems", L4DC 2020, section 5; the benchmark of their public code's tabular form,
re-implemented from its description).

A grid of ``height`` x ``width`` cells holds ``users`` users a cell; an access point stands at each of the grid's
(height - 1)(width - 1) inner corners and serves the users of the four cells around it; it delivers a packet with
its own probability q_y. User i's local state is its buffer (e_1, .., e_d): e_k = 1 where it holds a packet with k
steps left (d the deadline). At each step it either waits (action 0) or sends the packet of slot k to one of its
access points y (action 1 + k |Y_i| + the place of y in Y_i). A send reaches y when no other user sends to y at that
step; then, where the slot held a packet, it is delivered with probability q_y, the packet leaves the buffer and
the user's reward is 1. Then every packet's time left falls by one (those of slot 1 are lost) and a new packet of
deadline d arrives with probability p. A user's neighbours are the users that share an access point with it: its
next state and its reward depend on its own state and its neighbours' actions only (a networked MDP whose
transitions read the neighbourhood's actions, as in the paper's example). Every number is keyed by (seed, purpose
AGENT_STATE, step, user): u0 the arrival, u1 the delivery; an episode's first buffers by (AGENT_START, episode,
user) (`dgtd.streams`).

The published setting (`published`): 3 x 4 cells, 2 users a cell (24 users), 6 access points whose probabilities
are those of the public code (NumPy's legacy generator seeded 0), deadline 2, arrivals 0.5, gamma 0.7, horizon 10.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from dgtd.errors import DgtdInputError
from dgtd.streams import AGENT_START, AGENT_STATE, uniforms

# The access points' delivery probabilities of the published benchmark: the first six of
# numpy.random.RandomState(0).rand(), as its public code draws them
PUBLISHED_Q = (0.5488135039273248, 0.7151893663724195, 0.6027633760716439, 0.5448831829968969, 0.4236547993389047,
               0.6458941130666561)  # fmt: skip


@dataclass(frozen=True)
class WirelessAccess:
    """The task of the module's docstring: ``access`` (N, M) whether user i reaches access point y, ``q`` (M,) their
    delivery probabilities, ``deadline`` d, ``arrival`` p, ``gamma`` the discount."""

    access: np.ndarray
    q: np.ndarray
    deadline: int = 2
    arrival: float = 0.5
    gamma: float = 0.7
    name: str = "wireless-access"

    def __post_init__(self):
        N, M = self.access.shape
        if N < 1 or M < 1 or not self.access.any(axis=1).all():
            raise DgtdInputError("wireless access needs users, access points, and every user able to reach one")
        if self.q.shape != (M,) or not ((self.q >= 0) & (self.q <= 1)).all():
            raise DgtdInputError(f"the access points' delivery probabilities are {M} numbers in [0, 1]")
        if int(self.deadline) < 1 or not 0.0 <= self.arrival <= 1.0 or not 0.0 <= self.gamma < 1.0:
            raise DgtdInputError("wireless access needs a deadline >= 1, arrivals in [0, 1] and gamma in [0, 1)")

    @property
    def n_agents(self) -> int:
        return self.access.shape[0]

    @cached_property
    def points(self) -> list:
        """Each user's access points, ascending."""
        return [np.flatnonzero(row) for row in self.access]

    @property
    def actions(self) -> np.ndarray:
        """(N,) each user's action count: wait, or one of its d x |Y_i| sends."""
        return 1 + self.deadline * self.access.sum(axis=1)

    @property
    def observations(self) -> int:
        """The rows of a user's policy: its own buffer's 2^d states."""
        return 2**self.deadline

    @property
    def state_values(self) -> int:
        return 2**self.deadline

    @cached_property
    def neighbourhoods(self) -> np.ndarray:
        """(N, K) each user and those that share an access point with it, ascending after it, padded with -1 (from
        each access point's users: O(N K), not O(N^2))."""
        users = [np.flatnonzero(column) for column in self.access.T]
        rows = [[i, *sorted({int(j) for y in ys for j in users[y]} - {i})] for i, ys in enumerate(self.points)]
        out = np.full((self.n_agents, max(len(r) for r in rows)), -1, dtype=np.int64)
        for i, r in enumerate(rows):
            out[i, : len(r)] = r
        return out

    def first_states(self, keys: np.ndarray, m: int) -> np.ndarray:
        """(B, N) the buffers at episode m's start: a packet of deadline d with probability p (AGENT_START, m, user)."""
        u = uniforms(keys[:, None], AGENT_START, m, np.arange(self.n_agents))[0]
        return np.where(u < self.arrival, 1 << (self.deadline - 1), 0).astype(np.int64)

    def observe(self, s: np.ndarray) -> np.ndarray:
        """(B, N) each user's policy row: its own buffer."""
        return s

    @cached_property
    def point_table(self) -> np.ndarray:
        """(N, P) each user's access points, ascending, padded with -1 (P the most a user has)."""
        out = np.full((self.n_agents, max(len(ys) for ys in self.points)), -1, dtype=np.int64)
        for i, ys in enumerate(self.points):
            out[i, : len(ys)] = ys
        return out

    def sends(self, a: np.ndarray) -> tuple:
        """(slot, access point) of every user's action ``a`` (B, N): slot k in 0 .. d - 1 (bit k of the buffer), the
        access point's index; (-1, -1) where it waits."""
        counts = (self.point_table >= 0).sum(axis=1)
        k = np.maximum(a - 1, 0)
        slot, place = k // counts, k % counts
        point = self.point_table[np.arange(self.n_agents)[None, :], place]
        waits = a == 0
        return np.where(waits, -1, slot), np.where(waits, -1, point)

    def step(self, s: np.ndarray, a: np.ndarray, keys: np.ndarray, k: int) -> tuple:
        """(s' (B, N), r (B, N)) at step k from the buffers ``s`` and actions ``a``: collisions, deliveries, the
        deadlines' passing and arrivals (the module's docstring)."""
        B, N = s.shape
        slot, point = self.sends(a)
        senders = np.zeros((B, self.q.size), dtype=np.int64)
        b = np.broadcast_to(np.arange(B)[:, None], (B, N))
        np.add.at(senders, (b[point >= 0], point[point >= 0]), 1)
        u = uniforms(keys[:, None], AGENT_STATE, k, np.arange(N))
        alone = (point >= 0) & (senders[b, np.maximum(point, 0)] == 1)
        held = alone & ((s >> np.maximum(slot, 0)) & 1 == 1)
        delivered = held & (u[1] < self.q[np.maximum(point, 0)])
        left = np.where(delivered, s & ~(1 << np.maximum(slot, 0)), s) >> 1
        s_next = left | np.where(u[0] < self.arrival, 1 << (self.deadline - 1), 0)
        return s_next.astype(np.int64), delivered.astype(np.float64)

    def aloha(self, send: float) -> np.ndarray:
        """(N, 2^d, A_max) the ALOHA-like heuristic's local policies: holding a packet, send the earliest one with
        probability ``send``, to access point y with probability proportional to q_y / (the users it serves);
        otherwise wait."""
        N, A = self.n_agents, int(self.actions.max())
        served = self.access.sum(axis=0)
        out = np.zeros((N, self.observations, A))
        out[:, :, 0] = 1.0
        for i, ys in enumerate(self.points):
            weight = self.q[ys] / served[ys]
            weight = weight / weight.sum() if weight.sum() > 0 else np.full(len(ys), 1.0 / len(ys))
            for state in range(1, self.observations):
                earliest = (state & -state).bit_length() - 1
                out[i, state, 0] = 1.0 - send
                out[i, state, 1 + earliest * len(ys) + np.arange(len(ys))] = send * weight
        return out


def grid(height: int = 3, width: int = 4, users: int = 2, q=None, **settings) -> WirelessAccess:
    """Users on a ``height`` x ``width`` grid of cells, ``users`` a cell (user u of cell (r, c) is number
    users (r width + c) + u), an access point at each inner corner (row-major); ``q`` their delivery probabilities
    (default the published ones where there are 6, else those of `PUBLISHED_Q` repeated)."""
    if height < 2 or width < 2 or users < 1:
        raise DgtdInputError(f"a grid of access points needs 2 x 2 cells or more and a user a cell; got {height} x "
                             f"{width}, {users}")  # fmt: skip
    M = (height - 1) * (width - 1)
    access = np.zeros((height * width * users, M), dtype=bool)
    for y in range(M):
        corner = y // (width - 1) * width + y % (width - 1)  # the cell above and left of the point
        for cell in (corner, corner + 1, corner + width, corner + width + 1):
            access[users * cell : users * (cell + 1), y] = True
    q = np.resize(np.asarray(PUBLISHED_Q), M) if q is None else np.asarray(q, dtype=np.float64)
    return WirelessAccess(access, q, **settings)


def published() -> WirelessAccess:
    """The published benchmark: 3 x 4 cells, 2 users a cell, deadline 2, arrivals 0.5, gamma 0.7."""
    return grid(3, 4, 2)
