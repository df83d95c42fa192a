"""Base topologies as undirected edge lists: an (E, 2) int array with i < j, no self-loops, no repeats."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dgtd.errors import DgtdInputError
from dgtd.files import text_of


@dataclass(frozen=True, eq=False)
class Graph:
    """An undirected graph on nodes 0..n_nodes-1; ``edges`` (E, 2) with edges[e, 0] < edges[e, 1]. ``near``: its
    numbering puts neighbours near each other by construction (a chunked small-world's ring, a geometric graph's
    cells), so that runs keep it and seek no other (`dgtd.backends.compiled.graph.storage_order`)."""

    n_nodes: int
    edges: np.ndarray
    name: str = "graph"
    near: bool = False

    @property
    def n_edges(self) -> int:
        return self.edges.shape[0]

    def laplacian(self, weights=None) -> np.ndarray:
        """L = H - W (paper section 'Graph theory'), with edge weights (default 1), shape (N, N)."""
        w = np.ones(self.n_edges) if weights is None else np.asarray(weights, dtype=np.float64)
        L = np.zeros((self.n_nodes, self.n_nodes))
        u, v = self.edges[:, 0], self.edges[:, 1]
        np.add.at(L, (u, v), -w)
        np.add.at(L, (v, u), -w)
        np.add.at(L, (u, u), w)
        np.add.at(L, (v, v), w)
        return L

    def laplacian_sparse(self, weights=None):
        """The same Laplacian as a scipy CSR matrix: O(N + |E|) memory, for large graphs."""
        from scipy.sparse import coo_matrix

        w = np.ones(self.n_edges) if weights is None else np.asarray(weights, dtype=np.float64)
        u, v = self.edges[:, 0], self.edges[:, 1]
        deg = np.bincount(u, w, self.n_nodes) + np.bincount(v, w, self.n_nodes)
        rows = np.concatenate([u, v, np.arange(self.n_nodes)])
        cols = np.concatenate([v, u, np.arange(self.n_nodes)])
        vals = np.concatenate([-w, -w, deg])
        return coo_matrix((vals, (rows, cols)), shape=(self.n_nodes, self.n_nodes)).tocsr()


def all_reachable(adj: np.ndarray) -> bool:
    """Whether every node can be reached from node 0 along the dense boolean adjacency ``adj`` (n, n).

    A breadth-first search in NumPy: the checks that run before every run use it, so that starting dgtd does
    not import scipy.sparse.csgraph (a quarter of a second); the error paths use scipy for their details.
    """
    seen = np.zeros(adj.shape[0], dtype=bool)
    seen[0] = True
    frontier = seen.copy()
    while frontier.any():
        frontier = adj[frontier].any(axis=0) & ~seen
        seen |= frontier
    return bool(seen.all())


def from_edges(n_nodes: int, edges, name: str = "edges", near: bool = False) -> Graph:
    """Graph from any iterable of (i, j) pairs; duplicates and orientation are normalised (``near``: `Graph`'s)."""
    if int(n_nodes) < 1:
        raise DgtdInputError(f"a graph needs at least one node, got {n_nodes}")
    e = np.asarray(list(edges) if not isinstance(edges, np.ndarray) else edges, dtype=np.int64).reshape(-1, 2)
    if e.size and (e.min() < 0 or e.max() >= n_nodes):
        raise DgtdInputError(f"edge endpoints must lie in 0..{n_nodes - 1}, got {e.min()}..{e.max()}")
    if np.any(e[:, 0] == e[:, 1]):
        raise DgtdInputError("self-loops are not allowed in a communication graph")
    e = unique_edges(np.sort(e, axis=1), int(n_nodes))
    e.setflags(write=False)
    return Graph(int(n_nodes), e, name, near)


def unique_ints(x: np.ndarray) -> np.ndarray:
    """``np.unique`` of whole numbers (sorted, each once) by a sort: NumPy 2.4's own took 1.3-5.8 s on 4 million
    (hashing), a sort 0.08 s (measured on this machine)."""
    s = np.sort(np.asarray(x).ravel())
    return s[np.concatenate([[True], s[1:] != s[:-1]])] if s.size else s


def unique_edges(edges: np.ndarray, n_nodes: int) -> np.ndarray:
    """Rows (u, v) of whole numbers below ``n_nodes``, sorted and each once (``np.unique(edges, axis=0)``)."""
    code = unique_ints(edges[:, 0].astype(np.int64) * np.int64(n_nodes) + edges[:, 1])
    return np.stack([code // n_nodes, code % n_nodes], axis=1).astype(np.int64).reshape(-1, 2)


def path(n: int) -> Graph:
    return from_edges(n, [(i, i + 1) for i in range(n - 1)], "path")


def ring(n: int) -> Graph:
    if n < 3:
        return path(n)
    return from_edges(n, [(i, (i + 1) % n) for i in range(n)], "ring")


def star(n: int) -> Graph:
    return from_edges(n, [(0, i) for i in range(1, n)], "star")


def complete(n: int) -> Graph:
    i, j = np.triu_indices(n, k=1)
    return from_edges(n, np.stack([i, j], 1), "complete")


def ring_with_chords(n: int, chord: int) -> Graph:
    """Ring plus the edges i -- i + chord: a ring whose diameter shrinks by about ``chord``."""
    ring_e = [(i, (i + 1) % n) for i in range(n)]
    chords = [(i, (i + chord) % n) for i in range(n) if (i + chord) % n != i]
    return from_edges(n, ring_e + chords, f"ring+chords{chord}")


def from_networkx(G) -> Graph:
    """Graph from a networkx graph; nodes are numbered in sorted order (or insertion order if unsortable)."""
    nodes = list(G.nodes)
    try:
        nodes = sorted(nodes)
    except TypeError:
        pass
    index = {v: k for k, v in enumerate(nodes)}
    return from_edges(len(nodes), [(index[u], index[v]) for u, v in G.edges if u != v], "networkx")


def read_edge_list(path_: str) -> Graph:
    """Graph from a text file of 'i j' lines (0-based node numbers; '#' starts a comment)."""
    import networkx as nx

    try:
        lines = text_of(path_).splitlines()
    except FileNotFoundError:
        raise DgtdInputError(f"edge-list file {path_} does not exist") from None
    except (OSError, UnicodeDecodeError) as e:
        raise DgtdInputError(f"edge-list file {path_} cannot be read ({e})") from None
    for number, line in enumerate(lines, 1):  # networkx drops what follows the pair: say so rather than lose it
        columns = len(line.split("#", 1)[0].split())
        if columns not in (0, 2):
            raise DgtdInputError(
                f"edge-list file {path_}, line {number} has {columns} columns; write one 'i j' pair per line (a "
                "graph's links carry no weights here: their probabilities are --edge-prob)"
            )
    try:
        G = nx.parse_edgelist(lines, nodetype=int, data=False)  # (the lines as read, a BOM dropped)
    except (TypeError, ValueError, IndexError) as e:
        raise DgtdInputError(f"edge-list file {path_} is malformed ({e}); write one 'i j' pair per line") from None
    if G.number_of_nodes() == 0:
        raise DgtdInputError(f"edge-list file {path_} holds no edges")
    loops = sorted(u for u, v in G.edges if u == v)
    if loops:
        raise DgtdInputError(f"edge-list file {path_} links agent {loops[0]} to itself; a graph has no self-loops")
    n = max(G.nodes) + 1
    return from_edges(n, list(G.edges), f"file:{path_}")


TOPOLOGIES = {"path": path, "ring": ring, "star": star, "complete": complete, "erdos-renyi": complete}
