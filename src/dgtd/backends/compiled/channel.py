"""The compiled twin of `dgtd.channels.Perfect`: which neighbours an agent heard at a step, the aggregates of what
they sent (`dgtd.channels.Inbox`'s); the counts are `dgtd.channels.counted`'s. Tested equal to the NumPy definition.

Inside the driver (`dgtd.backends.compiled.driver`) an agent's inbox is an `Inbox` of plain arrays: the messages every
agent sent at step k, the storage rows of the neighbours heard (row ``at`` of ``heard``, ``count`` of them) and
scratch rows for the aggregates. A per-agent step asks for an aggregate of message m, which lands in
``inbox.sums[m, inbox.at]``, as its NumPy ``update`` asks ``inbox.laplacian(name)``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from dgtd.backends.compiled.simd import neighbour_sums, weighted_sums


class Inbox(NamedTuple):
    """What the agents a thread updates heard at step k (`dgtd.channels.Inbox`, one agent at a time): built once per
    step and thread, the agent's own part filled in by `hear` (an array of arrays made per agent would cost reference
    counts, with atomic instructions, at every agent-step)."""

    sent: np.ndarray  # every message at step k, (M, B, N, q), in storage rows
    heard: np.ndarray  # (rows, max degree): the storage rows of the neighbours the agent heard, in row ``at``
    n_heard: np.ndarray  # (rows, 8): how many, in row [at, 0] (a row a cache line)
    weights: np.ndarray  # (rows, max degree): their Metropolis weights, in row ``at`` (`metropolis` fills it)
    degree: np.ndarray  # (rows, N): how many messages each agent heard at this step, in row ``degree_row``
    degree_row: int
    sums: np.ndarray  # (M, rows, q) scratch: the aggregate of message m lands in row [m, at]
    at: int
    arc_weights: np.ndarray  # (2E,) the weight of what each arc delivers, where the channel reweighs it; else empty


@njit(cache=True, inline="always")
def hear(inbox, up, row, indptr, nbr, eid, i):
    """The storage rows of agent i's neighbours whose links are up (row ``row`` of the step's edge mask) into the
    inbox, and how many. Without a branch: links are up at random, and a branch would be mispredicted."""
    heard, at, reweighs = inbox.heard, inbox.at, inbox.arc_weights.shape[0] > 0
    n = 0
    for k in range(indptr[i], indptr[i + 1]):
        heard[at, n] = nbr[k]
        if reweighs:  # (then eid holds arc ids: `dgtd.backends.compiled.driver._graph`)
            inbox.weights[at, n] = inbox.arc_weights[eid[k]]
        n += up[row, eid[k]]
    inbox.n_heard[at, 0] = n


@njit(cache=True, inline="always")
def count_heard(up, row, indptr, eid, degree, degree_row):
    """degree[degree_row, i] = how many messages agent i hears at this step (its links up), for every agent: the d_i
    of the Metropolis weights."""
    for agent in range(indptr.shape[0] - 1):
        d = 0
        for k in range(indptr[agent], indptr[agent + 1]):
            d += up[row, eid[k]]
        degree[degree_row, agent] = d


@njit(cache=True, inline="always")
def laplacian(inbox, m, b, i):
    """sum_j (x_i - x_j) of message m over the neighbours heard, into inbox.sums[m, inbox.at]: (L(k) x)_i. Summed as
    d_i x_i - x_j1 - x_j2 - ... (`neighbour_sums`), which streams the neighbours' rows past registers once."""
    at = inbox.at
    if inbox.arc_weights.shape[0] > 0:  # sum_j c_ij (x_i - x_j), c_ij the arc's weight (`dgtd.channels.Lossy`)
        weighted_sums(inbox.sent, (m, b), i, inbox.heard, inbox.weights, at, inbox.n_heard[at, 0], inbox.sums, (m, at))  # type: ignore[call-arg]
        return
    neighbour_sums(inbox.sent, (m, b), i, inbox.heard, at, inbox.n_heard[at, 0], inbox.sums, (m, at))  # type: ignore[call-arg]


@njit(cache=True, inline="always")
def metropolis_weights(inbox, i):
    """W_ij = 1 / (1 + max(d_i, d_j)) of the neighbours agent i heard, into inbox.weights[inbox.at]: once per agent
    and step (the driver's, for a step that needs them), for every message that mixes with them."""
    at, deg, row = inbox.at, inbox.degree, inbox.degree_row
    for n in range(inbox.n_heard[at, 0]):
        inbox.weights[at, n] = 1.0 / (1.0 + max(deg[row, i], deg[row, inbox.heard[at, n]]))


@njit(cache=True, inline="always")
def metropolis(inbox, m, b, i):
    """sum_j W_ij (x_i - x_j) of message m, W_ij = 1 / (1 + max(d_i, d_j)) (`metropolis_weights`), into
    inbox.sums[m, inbox.at]; each term added in the order of the neighbours, as `dgtd.channels.Inbox.metropolis`
    adds them."""
    at = inbox.at
    weighted_sums(inbox.sent, (m, b), i, inbox.heard, inbox.weights, at, inbox.n_heard[at, 0], inbox.sums, (m, at))  # type: ignore[call-arg]


@njit(cache=True, inline="always")
def total(inbox, m, b, i):
    """sum_j x_j of message m over the neighbours heard, into inbox.sums[m, inbox.at]."""
    x, out, at = inbox.sent, inbox.sums, inbox.at
    q = x.shape[3]
    for f in range(q):
        out[m, at, f] = 0.0
    for n in range(inbox.n_heard[at, 0]):
        j = inbox.heard[at, n]
        for f in range(q):
            out[m, at, f] += x[m, b, j, f]
