"""Proximity networks: agents with positions are linked whenever they are within a communication radius.

Unlike `dgtd.graphs.random.RandomEdges`, the links are not i.i.d. over time: they are a function of the
agents' positions, recomputed at every step, so they inherit the motion's correlations. Any model that
moves agents in a metric space can use this: pass positions (..., N, dim) to `ProximityNetwork.masks`.

The run loop still needs a `RandomEdges` for the mean Laplacian (mu* of Proposition 5), the
connectivity assumption and the kernels' edge list: `LinkStats.mean_network()` gives the complete graph
with p_e = the observed frequency of each link (the mean graph), while a sample source supplies the actual
per-step masks over the same edge list (see `dgtd.scenarios.robots.PatrolSource`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from dgtd.errors import DgtdInputError
from dgtd.graphs.random import RandomEdges, random_edges
from dgtd.graphs.topologies import Graph, complete


@dataclass(frozen=True, eq=False)
class ProximityNetwork:
    """Edge {i, j} is up at a step exactly when |x_i - x_j|_2 <= ``radius`` (inclusive) at that step.

    ``base`` is the complete graph on ``n_nodes`` agents; masks are over its edge list, in its order.
    """

    n_nodes: int
    radius: float

    def __post_init__(self):
        if int(self.n_nodes) < 1:
            raise DgtdInputError(f"a proximity network needs at least one agent, got {self.n_nodes}")
        if not (np.isfinite(self.radius) and self.radius >= 0):
            raise DgtdInputError(f"the communication radius must be a finite number >= 0, got {self.radius}")

    @cached_property
    def base(self) -> Graph:
        return complete(int(self.n_nodes))

    @property
    def n_edges(self) -> int:
        return self.base.n_edges

    def masks(self, positions: np.ndarray) -> np.ndarray:
        """Edges up (..., E) bool from positions (..., N, dim)."""
        return proximity_masks(positions, self.base.edges, self.radius)

    def describe(self) -> str:
        return f"proximity network on {self.n_nodes} agents: link when distance <= {self.radius:g}"


def proximity_masks(positions: np.ndarray, edges: np.ndarray, radius: float) -> np.ndarray:
    """Edges up (..., E) bool: |x_u - x_v|^2 <= radius^2 for each edge (u, v) of ``edges`` (E, 2).

    Squared distances are compared with radius^2 so that a pair exactly at the radius (e.g. a 3-4-5 triangle)
    is linked, as the inclusive rule says, without a square root's rounding.
    """
    x = np.asarray(positions, dtype=np.float64)
    diff = x[..., edges[:, 0], :] - x[..., edges[:, 1], :]
    return np.einsum("...ed,...ed->...e", diff, diff) <= float(radius) ** 2


def is_connected(masks: np.ndarray, edges: np.ndarray, n_nodes: int) -> np.ndarray:
    """Whether the graph of each mask (..., E) is connected, (...) bool, vectorised over the leading axes.

    Node 0 reaches everything within N - 1 hops: the reach set grows by one adjacency product per round,
    with ceil(log2(N)) squarings of (I + A) instead of N - 1 products.
    """
    masks = np.asarray(masks, dtype=bool)
    lead = masks.shape[:-1]
    N = int(n_nodes)
    if N <= 1:
        return np.ones(lead, dtype=bool)
    A = np.zeros(lead + (N, N))
    A[..., edges[:, 0], edges[:, 1]] = masks
    A[..., edges[:, 1], edges[:, 0]] = masks
    reach = A + np.eye(N)
    for _ in range(int(np.ceil(np.log2(N - 1)))):
        reach = np.minimum(reach @ reach, 1.0)  # capped so that powers of large graphs do not overflow
    return np.all(reach[..., 0, :] > 0, axis=-1)


@dataclass(frozen=True)
class LinkStats:
    """Counts over the steps seen so far: how often each edge was up, and how often the graph was connected.

    Updated by the pure function `count_links`; ``up`` (E,) and ``connected`` are summed over steps and seeds.
    """

    steps: int
    up: np.ndarray
    connected: int

    @property
    def link_frequency(self) -> np.ndarray:
        """The mean graph: p_e = fraction of steps edge e was up, (E,)."""
        return self.up / max(self.steps, 1)

    @property
    def connected_fraction(self) -> float:
        return self.connected / max(self.steps, 1)

    def mean_network(self, base: Graph) -> RandomEdges:
        """The complete graph with p_e = link frequencies: what E[L(k)] is under the observed motion."""
        return random_edges(base, self.link_frequency)

    def as_dict(self, base: Graph) -> dict:
        return {
            "steps": int(self.steps),
            "connected_fraction": float(self.connected_fraction),
            "edges": base.edges.tolist(),
            "link_frequency": self.link_frequency.tolist(),
        }


def empty_stats(n_edges: int) -> LinkStats:
    return LinkStats(0, np.zeros(n_edges, dtype=np.int64), 0)


def count_links(stats: LinkStats, masks: np.ndarray, edges: np.ndarray, n_nodes: int) -> LinkStats:
    """Add the masks (..., E) of more steps (any leading axes: time, seeds, teams) to ``stats``."""
    E = edges.shape[0]
    m = np.asarray(masks, dtype=bool).reshape(-1, E)
    if E <= 30:  # few agents: few distinct graphs, each tested once (a mask is read as the bits of an integer)
        bits = np.int64(1) << np.arange(E, dtype=np.int64)
        codes, times = np.unique(m.astype(np.int64) @ bits, return_counts=True)
        patterns = (codes[:, None] & bits) > 0
    else:
        patterns, times = m, np.ones(m.shape[0], np.int64)
    return LinkStats(
        stats.steps + m.shape[0],
        stats.up + m.sum(axis=0),
        stats.connected + int(times[is_connected(patterns, edges, n_nodes)].sum()),
    )
