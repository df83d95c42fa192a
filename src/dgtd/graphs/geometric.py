"""A random geometric graph made of keyed cells (`dgtd.graphs.chunked`'s ``geometric`` kind): N agents uniform in the
unit square, each pair within distance r linked, any band of agents made alone.

The square is cut into G x G cells of side 1 / G >= r, numbered row by row, and the agents are numbered cell by
cell, so that a contiguous range of agents is a band of cells and every agent within r of it lies in the band and the
rows of cells either side (as KaGen's generators cut the square; Funke, Lamm, Meyer, Penschuck, Sanders, Schulz,
Strash and von Looz 2019). How many agents a cell holds is multinomial(N; 1 / G^2 each), drawn as a tree of binomial
splits (the cells [c0, c1) split at their middle, the left part's count Binomial(n, share) by inversion of one keyed
uniform of the tree node), so that a range of cells' counts, and the first agent of each, need only the nodes above
them: O(cells + log G) numbers. A cell's agents sit at keyed uniforms of the cell. Every number is keyed by (the
graph's seed, purpose GRAPH, the node or cell, its place): a pure function of the seed, whatever the ranks.

The radius is the one whose expected degree is the mean degree asked for, border included: a point uniform in the
unit square has (N - 1)(pi r^2 - 8 r^3 / 3 + r^4 / 2) neighbours on average, for r <= 1.
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np

from dgtd.streams import GRAPH, uniforms


class ChunkedGraph(Protocol):
    """What this module reads of a `dgtd.graphs.chunked.ChunkedGraph` (which imports it)."""

    @property
    def n_agents(self) -> int: ...
    @property
    def mean_degree(self) -> float: ...
    @property
    def key(self) -> np.uint64: ...


SPLITS, POINTS = 1, 2  # the uniforms' index of a tree node's split and of a cell's points


def mean_degree_at(radius: float, n_agents: int) -> float:
    """The expected degree of an agent of a random geometric graph of ``n_agents`` in the unit square."""
    r = radius
    return (n_agents - 1) * (math.pi * r * r - 8.0 * r**3 / 3.0 + r**4 / 2.0)


def radius(g: ChunkedGraph) -> float:
    """The radius whose expected degree is the graph's mean degree (bisection: the degree rises with r on [0, 1])."""
    if g.mean_degree >= mean_degree_at(1.0, g.n_agents):
        return math.sqrt(2.0)  # every pair (within the square's diagonal)
    lo, hi = 0.0, 1.0
    for _ in range(100):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if mean_degree_at(mid, g.n_agents) < g.mean_degree else (lo, mid)
    return hi


def grid(g: ChunkedGraph) -> int:
    """G, the cells a side: of side 1 / G >= r, at most 2^15 (so that G^2 cells and their tree's nodes number
    below 2^32)."""
    return int(max(1, min(1 << 15, math.floor(1.0 / radius(g)))))


def _binomial(u: np.ndarray, n: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Binomial(n, p) by inversion of ``u``: the least k with P(X <= k) >= u."""
    from scipy.stats import binom

    k = binom.ppf(u, n, p)
    return np.clip(np.nan_to_num(k), 0, n).astype(np.int64)


def cell_counts(g: ChunkedGraph, cells: range) -> tuple[np.ndarray, np.ndarray]:
    """The agents of every cell of ``cells`` and the first agent's id of each: the tree of splits descended into the
    nodes that overlap the range, a level at a time (node h's children 2h and 2h + 1, the root 1)."""
    C = grid(g) ** 2
    a, b = max(cells.start, 0), min(cells.stop, C)
    counts, first = np.zeros(max(b - a, 0), np.int64), np.zeros(max(b - a, 0), np.int64)
    if b <= a:
        return counts, first
    c0, c1, n, h, start = (np.array([x], np.int64) for x in (0, C, g.n_agents, 1, 0))
    while len(c0):
        leaf = c1 - c0 == 1
        at = c0[leaf] - a
        counts[at], first[at] = n[leaf], start[leaf]
        c0, c1, n, h, start = (x[~leaf] for x in (c0, c1, n, h, start))
        mid = (c0 + c1) // 2
        u, _ = uniforms(g.key, GRAPH, np.uint64(0), h.astype(np.uint64), SPLITS)
        left = _binomial(u, n, (mid - c0) / (c1 - c0))
        c0, c1 = np.concatenate([c0, mid]), np.concatenate([mid, c1])
        n, h = np.concatenate([left, n - left]), np.concatenate([2 * h, 2 * h + 1])
        start = np.concatenate([start, start + left])
        keep = (c1 > a) & (c0 < b)
        c0, c1, n, h, start = (x[keep] for x in (c0, c1, n, h, start))
    return counts, first


def cell_of(g: ChunkedGraph, agent: int) -> int:
    """The cell holding ``agent``: the tree descended along the child whose agents include it."""
    c0, c1, n, h, start = 0, grid(g) ** 2, g.n_agents, 1, 0
    while c1 - c0 > 1:
        mid = (c0 + c1) // 2
        u, _ = uniforms(g.key, GRAPH, np.uint64(0), np.uint64(h), SPLITS)
        left = int(_binomial(np.array([u]), np.array([n]), np.array([(mid - c0) / (c1 - c0)]))[0])
        if agent < start + left:
            c1, n, h = mid, left, 2 * h
        else:
            c0, n, h, start = mid, n - left, 2 * h + 1, start + left
    return c0


def points(g: ChunkedGraph, cells: range) -> tuple[np.ndarray, np.ndarray]:
    """The ids (n,) and positions (n, 2) of every agent of ``cells``, in id order: cell c's k-th agent at
    ((x + u) / G, (y + u') / G), c = y G + x, (u, u') the k-th call of the cell's stream."""
    G = grid(g)
    counts, first = cell_counts(g, cells)
    cell = np.repeat(np.arange(cells.start, cells.start + len(counts), dtype=np.int64), counts)
    k = np.arange(counts.sum(), dtype=np.int64) - np.repeat(np.cumsum(counts) - counts, counts)
    u0, u1 = uniforms(g.key, GRAPH, k.astype(np.uint64), cell.astype(np.uint64), POINTS)
    xy = np.stack([(cell % G + u0) / G, (cell // G + u1) / G], axis=1)
    return np.repeat(first, counts) + k, xy


def edges_touching(g: ChunkedGraph, lo: int, hi: int) -> np.ndarray:
    """The edges (u, v), u < v, sorted, with an end among the agents lo .. hi - 1: the pairs within r among their
    band of cells and the rows of cells either side."""
    from scipy.spatial import cKDTree

    G = grid(g)
    rows = cell_of(g, lo) // G, cell_of(g, hi - 1) // G
    cells = range(max(rows[0] - 1, 0) * G, min(rows[1] + 2, G) * G)
    ids, xy = points(g, cells)
    pairs = cKDTree(xy).query_pairs(radius(g), output_type="ndarray")
    ends = ids[pairs]
    ends = np.sort(ends, axis=1)
    return ends[((ends >= lo) & (ends < hi)).any(axis=1)]
