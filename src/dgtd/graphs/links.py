"""The links up at one step, as the operators an algorithm applies: the one place a link model plugs in.

An algorithm never sees edges: it asks ``links.laplacian(X)`` for (L(k) X)_i = sum over links {i, j} up at step k
of (X_i - X_j), the neighbour sums of Algorithm 1 (section 7 of the paper), or ``links.metropolis(X)`` for the
same sum weighted by the Metropolis weights, so that sum_j W_ij(k) X_j = X_i - (L_W(k) X)_i.
"""

from __future__ import annotations

import numpy as np

from dgtd.graphs.random import LaplacianOperator


def metropolis_weights(edges: np.ndarray, up: np.ndarray, n_nodes: int) -> np.ndarray:
    """W_ij = 1 / (1 + max(d_i, d_j)) on each edge (i, j) up, else 0; ``up`` (..., E) bool -> (..., E) float.

    d_i is agent i's number of links up; W(k) is then symmetric and doubly stochastic for every graph.
    """
    up = np.asarray(up, dtype=np.float64)
    ends = np.zeros((edges.shape[0], n_nodes))
    ends[np.arange(edges.shape[0]), edges[:, 0]] = 1.0
    ends[np.arange(edges.shape[0]), edges[:, 1]] = 1.0
    deg = up @ ends  # (..., N): links up at each agent
    return up / (1.0 + np.maximum(deg[..., edges[:, 0]], deg[..., edges[:, 1]]))


class Links:
    """The links up at step k for B seeds: ``up`` (B, E) bool, or None when every edge of the graph is up."""

    def __init__(self, operator: LaplacianOperator, up: np.ndarray | None, n_seeds: int):
        self.operator, self.up, self.n_seeds = operator, up, n_seeds

    @classmethod
    def fixed(cls, operator: LaplacianOperator, n_seeds: int) -> "Links":
        return cls(operator, None, n_seeds)

    def laplacian(self, X: np.ndarray) -> np.ndarray:
        """(L(k) X)_i along the agent axis of X (B, N, q)."""
        return self.operator(X, self.up)

    def metropolis(self, X: np.ndarray) -> np.ndarray:
        """(L_W(k) X)_i: the Laplacian weighted by the Metropolis weights of the links up."""
        graph = self.operator.graph
        up = np.ones((self.n_seeds, graph.n_edges), dtype=bool) if self.up is None else self.up
        return self.operator(X, metropolis_weights(graph.edges, up, graph.n_nodes))
