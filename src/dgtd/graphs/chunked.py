"""Sparse random graphs made of keyed chunks: any part of the edge list can be made anywhere, and is the same.

The agents are cut into blocks of `BLOCK` agents (the last one shorter): how many blocks depends on N alone, never on
how many ranks run. Every random number is keyed (`dgtd.streams`, purpose GRAPH; the key the run's base seed's, its
entity the chunk it is for, its step the number's place in the chunk), so a rank makes only the chunks that touch its
agents and learns its ghosts from them, and the edges touching any set of agents are the same on 1 rank or 8.
Unlike KaGen's generators (a chunk's seed the run's seed plus the chunk's index, so that consecutive seeds share
streams), a chunk's numbers are a pure function of (seed, chunk): no two seeds share one.

- `erdos_renyi` (G(N, p) with p = d / (N - 1), d the mean degree): chunk (I, J), I <= J, holds the pairs of blocks I
  and J (u < v within a block); the gaps between its edges, in the pairs' row-major order, are geometric(p), drawn by
  inversion from the chunk's uniforms (Batagelj and Brandes 2005): O(edges) time, no pair visited.
- `small_world` (Watts and Strogatz 1998): the ring lattice linking each agent to the k / 2 next along the ring,
  each such link's far end moved, with probability ``rewire``, to an agent uniform over the others. Agent u's links
  are keyed by u (chunk: u's block); a moved link that repeats another, or one of the lattice's, is dropped, so the
  graph has about N k / 2 edges. Where a link lands is anyone's: the edges touching a block need every block's draws
  (N k / 2 numbers, streamed a block at a time; O(block) memory).
- `geometric` (a random geometric graph: agents uniform in the unit square, linked within the radius whose expected
  degree is d): the agents are numbered by cells of the square, so a range of them is a band of cells, and its edges
  need only the band and the rows of cells either side (`dgtd.graphs.geometric`).

`edges_touching(spec, agents)` gives the edges with an end among ``agents`` (sorted, each (u, v) with u < v), made from
the chunks that can touch them; `whole(spec)` the whole edge list as a `Graph` (the same function over every agent).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dgtd.errors import DgtdInputError
from dgtd.graphs import geometric
from dgtd.graphs.topologies import unique_edges
from dgtd.streams import GRAPH, seed_key, uniforms

BLOCK = 1 << 16  # agents a block: chunks of 2^32 pairs at most; chunk ids below 2^32 up to 2^32 agents


@dataclass(frozen=True)
class ChunkedGraph:
    """A keyed random graph: ``kind`` ("erdos-renyi", "small-world" or "geometric") on ``n_agents``, mean degree
    ``mean_degree`` (small-world: the lattice's k, even), small-world's ``rewire`` probability, drawn from base seed
    ``seed``'s streams, in blocks of ``block`` agents."""

    kind: str
    n_agents: int
    mean_degree: float
    rewire: float = 0.1
    seed: int = 0
    block: int = BLOCK  # agents a block (a property of the graph: the tests take small ones)

    def __post_init__(self):
        N, d = self.n_agents, self.mean_degree
        if self.kind not in KINDS:
            raise DgtdInputError(f"chunked graphs are {', '.join(KINDS)}; got {self.kind!r}")
        if N < 2:
            raise DgtdInputError(f"a {self.kind} graph needs at least 2 agents, got {N}")
        if not (np.isfinite(d) and 0 < d <= N - 1):
            name = {kind: given for given, kind in NAMES.items()}.get(self.kind, self.kind)
            raise DgtdInputError(
                f"--mean-degree: a {name} graph's mean degree lies in (0, N - 1] = (0, {N - 1}] on {N} agents; "
                f"got {d:g}"
            )
        if self.kind == "small-world" and (d != int(d) or int(d) % 2):
            raise DgtdInputError(f"a small-world graph links each agent to k / 2 on each side: k even, got {d}")
        if not 0.0 <= self.rewire <= 1.0:
            raise DgtdInputError(f"the rewiring probability lies in [0, 1], got {self.rewire}")

    @property
    def n_blocks(self) -> int:
        return -(-self.n_agents // self.block)

    @property
    def key(self) -> np.uint64:
        return np.uint64(seed_key(self.seed, 0))

    def describe(self) -> str:
        if self.kind == "small-world":
            return f"small-world (k = {int(self.mean_degree)}, rewired with p = {self.rewire:g})"
        if self.kind == "geometric":
            return f"random geometric (mean degree {self.mean_degree:g}, radius {geometric.radius(self):.3g})"
        return f"sparse Erdos-Renyi (mean degree {self.mean_degree:g})"


KINDS = ("erdos-renyi", "small-world", "geometric")
NAMES = {
    "small-world": "small-world",
    "sparse-random": "erdos-renyi",
    "geometric": "geometric",
}  # as --graph names them -> their kind
NUMBERED_NEAR = ("small-world", "geometric")  # kinds whose agents' numbering puts neighbours near (a ring, cells)


def _block(g: ChunkedGraph, b: int) -> tuple[int, int]:
    return b * g.block, min((b + 1) * g.block, g.n_agents)


def _draws(g: ChunkedGraph, entity: int, start: int, count: int, index: int = 0) -> np.ndarray:
    """Uniforms start .. start + count - 1 of a chunk's stream (two a call, calls keyed by their place)."""
    calls = np.arange(start // 2, (start + count + 1) // 2, dtype=np.uint64)
    u0, u1 = uniforms(g.key, GRAPH, calls, entity, index)
    both = np.stack([u0, u1], axis=-1).ravel()
    return both[start % 2 : start % 2 + count]


def erdos_renyi_chunk(g: ChunkedGraph, bi: int, bj: int) -> np.ndarray:
    """The edges (E, 2), u < v, of chunk (I, J) of an Erdos-Renyi graph (I <= J), in row-major order of the pairs."""
    (a0, a1), (b0, b1) = _block(g, bi), _block(g, bj)
    rows, cols = a1 - a0, b1 - b0
    pairs = rows * (rows - 1) // 2 if bi == bj else rows * cols
    p = g.mean_degree / (g.n_agents - 1)
    if pairs == 0 or p <= 0:
        return np.zeros((0, 2), np.int64)
    entity = bi * g.n_blocks + bj
    found, at, drawn, batch = [], -1, 0, max(64, int(pairs * p * 1.1) + 64)
    while at < pairs:
        u = _draws(g, entity, drawn, batch)
        drawn += batch
        gaps = np.zeros(batch, np.int64) if p >= 1 else np.floor(np.log1p(-u) / np.log1p(-p)).astype(np.int64)
        places = at + np.cumsum(gaps + 1)
        found.append(places[places < pairs])
        at = int(places[-1])
    index = np.concatenate(found)
    if bi != bj:
        return np.stack([a0 + index // cols, b0 + index % cols], axis=1)
    r = _triangle_row(index, rows)
    return np.stack([a0 + r, a0 + index - (r * rows - r * (r + 1) // 2) + r + 1], axis=1)


def _triangle_row(index: np.ndarray, n: int) -> np.ndarray:
    """The row r of pair ``index`` in the row-major order of the pairs (r, c), r < c < n: the largest r with
    r n - r (r + 1) / 2 <= index (a float estimate, corrected by one either way)."""
    b = 2 * n - 1
    r = np.floor((b - np.sqrt(np.maximum(b * b - 8.0 * index, 0.0))) / 2).astype(np.int64)
    start = lambda r: r * n - r * (r + 1) // 2  # noqa: E731
    r = np.where(start(r) > index, r - 1, r)
    return np.where(start(r + 1) <= index, r + 1, r)


def small_world_chunk(g: ChunkedGraph, bi: int) -> np.ndarray:
    """The links of block I's agents u (E, 2), u < v, each of u's k / 2 lattice links to u + j (j = 1 .. k/2, mod N)
    moved with probability ``rewire`` to an agent uniform over the others (two numbers of u's stream, index j)."""
    a0, a1 = _block(g, bi)
    N, half = g.n_agents, int(g.mean_degree) // 2
    u = np.arange(a0, a1, dtype=np.int64)
    ends = []
    for j in range(1, half + 1):
        move, where = uniforms(g.key, GRAPH, np.uint64(0), u.astype(np.uint64), j)
        other = np.minimum((where * (N - 1)).astype(np.int64), N - 2)
        other += other >= u  # uniform over the agents but u
        ends.append(np.where(move < g.rewire, other, (u + j) % N))
    v = np.stack(ends, axis=1).ravel()
    uu = np.repeat(u, half)
    return np.stack([np.minimum(uu, v), np.maximum(uu, v)], axis=1)


def edges_touching(g: ChunkedGraph, agents: range) -> np.ndarray:
    """The edges (E, 2), sorted and unique, with an end among the contiguous ``agents``: made from the chunks that can
    touch them (Erdos-Renyi: the chunks of their blocks; small-world: every block's, streamed; geometric: their band
    of cells and the rows either side), the same whatever the grouping of the agents (tested)."""
    lo, hi = agents.start, agents.stop
    if hi <= lo:
        return np.zeros((0, 2), np.int64)
    if g.kind == "geometric":
        return _sorted_unique(geometric.edges_touching(g, lo, hi), g.n_agents)
    mine = range(lo // g.block, (hi - 1) // g.block + 1)
    if g.kind == "erdos-renyi":
        chunks = [(min(bi, bj), max(bi, bj)) for bi in mine for bj in range(g.n_blocks) if bj >= bi or bj not in mine]
        pieces = [erdos_renyi_chunk(g, bi, bj) for bi, bj in chunks]
    else:
        pieces = [small_world_chunk(g, bi) for bi in range(g.n_blocks)]
    kept = [e[((e >= lo) & (e < hi)).any(axis=1)] for e in pieces]
    return _sorted_unique(np.concatenate(kept), g.n_agents)


def whole(g: ChunkedGraph):
    """The whole graph, a `dgtd.graphs.topologies.Graph`: `edges_touching` every agent."""
    from dgtd.graphs.topologies import Graph

    return Graph(g.n_agents, edges_touching(g, range(g.n_agents)), g.kind, near=g.kind in NUMBERED_NEAR)


def _sorted_unique(edges: np.ndarray, n: int) -> np.ndarray:
    """Edges (u, v), u < v < n, without self-loops or repeats, in increasing (u, v)."""
    return unique_edges(edges[edges[:, 0] != edges[:, 1]], n)
