"""Random communication networks (paper subsection 'Random communication network').

A network process gives, at each step k, the set of edges that are up. Every process here is i.i.d. over
time: each edge e of a base graph is up with probability p_e, independently. A fixed graph is p_e = 1;
an Erdos-Renyi graph drawn fresh each step is the complete base graph with p_e = p.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dgtd.errors import DgtdInputError
from dgtd.graphs.topologies import Graph


@dataclass(frozen=True, eq=False)
class RandomEdges:
    """Each edge of ``base`` is up with probability ``p`` (scalar or (E,)) at each step, i.i.d. over time."""

    base: Graph
    p: np.ndarray

    @property
    def n_nodes(self) -> int:
        return self.base.n_nodes

    @property
    def n_edges(self) -> int:
        return self.base.n_edges

    @property
    def fixed(self) -> bool:
        """True when every edge is always up: no random draws are needed."""
        return bool(np.all(self.p >= 1.0))

    def mean_laplacian(self, sparse: bool = False):
        """The mean Laplacian bold-L = E[L(k)] = sum_e p_e L_e (dense, or scipy CSR with ``sparse``)."""
        return self.base.laplacian_sparse(self.p) if sparse else self.base.laplacian(self.p)

    def masks_from_uniforms(self, u: np.ndarray) -> np.ndarray:
        """Edges up, (..., E) bool, from uniforms u (..., E): edge e is up when u_e < p_e."""
        return u < self.p

    def describe(self) -> str:
        if self.n_edges == 0:
            return f"{self.base.name} on {self.n_nodes} agent{'s' if self.n_nodes != 1 else ''}, no links"
        p = np.unique(self.p)
        ps = f"p={p[0]:g}" if p.size == 1 else f"p in [{p.min():g}, {p.max():g}]"
        return f"{self.base.name} on {self.n_nodes} agents, {self.n_edges} edges, each up with {ps}"


def as_network(network) -> RandomEdges:
    """A network as the runs take it: a `RandomEdges` as it is, a bare `Graph` as its fixed network (every link up);
    anything else one line."""
    if isinstance(network, Graph):
        return random_edges(network, 1.0)
    if not (hasattr(network, "base") and hasattr(network, "p")):
        raise DgtdInputError(
            f"a network is dgtd.random_edges(graph, p) (or a graph, every link up), not {type(network).__name__}"
        )
    return network


def random_edges(base: Graph, p=1.0) -> RandomEdges:
    """Build and validate a `RandomEdges` process, refusing a disconnected mean graph."""
    p = np.broadcast_to(np.asarray(p, dtype=np.float64), (base.n_edges,)).copy()
    if not np.all(np.isfinite(p)) or np.any((p < 0) | (p > 1)):
        raise DgtdInputError(f"edge probabilities must lie in [0, 1], got {np.unique(p)[:5].tolist()}")
    p.setflags(write=False)
    process = RandomEdges(base, p)
    check_mean_connected(process)
    return process


def check_mean_connected(process: RandomEdges) -> None:
    """Assumption Assumption 2 (mean connectivity): the mean connectivity graph (edges with p_e > 0) is connected."""
    from dgtd.graphs.topologies import all_reachable

    N = process.n_nodes
    if N == 1:
        return
    up = process.base.edges[process.p > 0]
    if N <= 2000:  # dense breadth-first search: no scipy import on the common path
        A = np.zeros((N, N), dtype=bool)
        A[up[:, 0], up[:, 1]] = A[up[:, 1], up[:, 0]] = True
        if all_reachable(A):
            return
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    A = coo_matrix((np.ones(len(up)), (up[:, 0], up[:, 1])), shape=(N, N))  # O(N + |E|) for many agents
    n, labels = connected_components(A, directed=False)
    if n > 1:
        alone = np.flatnonzero(labels != labels[0])[:5].tolist()
        raise DgtdInputError(
            f"the mean communication graph is disconnected ({n} components; e.g. agents {alone} cannot reach agent 0); "
            "add edges or raise the edge probability so that every agent is connected (the mean connectivity "
            "assumption)"
        )


LANCZOS_WORK = 2e9  # stored entries x products beyond which the smallest non-zero eigenvalue is bounded (~5 s)


def spectrum_ends(L) -> tuple[float, float, str]:
    """(the largest eigenvalue, the smallest non-zero one, how the latter was found) of a connected graph's
    symmetric mean mixing Laplacian ``L`` (scipy sparse, rows summing to 0), in O(|E|) memory: both by Lanczos
    (ARPACK's ``eigsh``, from a fixed start vector, so the same on every run), the smallest non-zero one as the
    smallest of L + lambda_max 11^T / N, whose eigenvalue along 1 is moved to the top (asked for two of L's
    smallest, ARPACK may return lambda_2 and lambda_3 and miss the 0). Where that does not converge within
    `LANCZOS_WORK` (a long ring's, about (2 pi / N)^2, would take many thousands of products), Mohar's bound
    lambda_2 >= 4 w_min / (N D) (Mohar 1991, eq. (6.10); w_min the smallest link weight, D the diameter, at most
    twice the eccentricity of agent 0, found by one breadth-first search): a smaller value, so a step rule that
    asks every eigenvalue to contract is the more cautious for it."""
    from scipy.sparse.csgraph import shortest_path
    from scipy.sparse.linalg import ArpackNoConvergence, LinearOperator, eigsh

    N = L.shape[0]
    # a fixed start vector, with a part along every eigenvector (a smooth one, as cos(i), misses a ring's slow modes)
    start = np.random.default_rng(0).standard_normal(N)
    largest = float(eigsh(L, k=1, which="LA", tol=1e-10, v0=start, return_eigenvectors=False)[0])
    restarts = int(LANCZOS_WORK / (20 * max(L.nnz, 1)))  # each restart about 20 products with L
    if restarts >= 2:
        lifted = LinearOperator((N, N), matvec=lambda x: L @ x + largest * x.mean(), dtype=np.float64)
        try:
            smallest = eigsh(lifted, k=1, which="SA", tol=1e-8, v0=start, maxiter=restarts, return_eigenvectors=False)
            return largest, float(smallest[0]), "Lanczos"
        except ArpackNoConvergence:
            pass
    links = L.tocoo()
    off = links.row != links.col
    weight = -links.data[off]
    linked = weight > 0
    adjacency = type(links)((weight[linked], (links.row[off][linked], links.col[off][linked])), shape=L.shape)
    eccentricity = float(shortest_path(adjacency, unweighted=True, indices=0).max())
    return largest, 4.0 * float(weight[linked].min()) / (N * 2.0 * eccentricity), "Mohar's bound"


def laplacian_pinv(L: np.ndarray) -> np.ndarray:
    """Pseudo-inverse of a connected graph's Laplacian, L^+ = (L + 11^T/N)^-1 - 11^T/N (Lemma 2)."""
    N = L.shape[0]
    J = np.full((N, N), 1.0 / N)
    return np.linalg.inv(L + J) - J
