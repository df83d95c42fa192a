"""Graphs for the compiled kernels: CSR neighbour lists with edge ids and the storage order of the agents."""

from __future__ import annotations

import numpy as np


def per_run(ctx, key: str, build):
    """``build()``, computed once per run context and kept on it (arrays the kernels read at every block)."""
    cache = ctx.__dict__.setdefault("_numba_cache", {})
    if key not in cache:
        cache[key] = build()
    return cache[key]


def csr_adjacency(edges: np.ndarray, n_nodes: int):
    """Neighbour lists with edge ids: for node i, nbr[indptr[i]:indptr[i+1]] and their edges eid[...]."""
    E = edges.shape[0]
    ends = np.concatenate([edges[:, 0], edges[:, 1]])
    others = np.concatenate([edges[:, 1], edges[:, 0]])
    ids = np.concatenate([np.arange(E), np.arange(E)])
    order = np.lexsort((others, ends))
    indptr = np.zeros(n_nodes + 1, np.int64)
    np.add.at(indptr, ends + 1, 1)
    return np.cumsum(indptr), others[order].astype(np.int64), ids[order].astype(np.int64)


def graph_arrays(ctx):
    """CSR arrays of the base graph, computed once per run context."""
    return per_run(ctx, "csr", lambda: csr_adjacency(ctx.network.base.edges, ctx.network.n_nodes))


RELABEL_MIN_AGENTS = 256


NEARBY_ROWS = 32  # edges whose ends sit at most this many rows apart count as local (`_local_fraction`)


def storage_order(ctx):
    """(order, inverse) of the agents in the DGTD kernels' arrays: row r holds agent order[r], agent i sits in row
    inverse[i]. From RELABEL_MIN_AGENTS agents on, a reverse Cuthill-McKee ordering puts neighbours in nearby
    rows, so that the rows an agent reads are mostly in cache already, when it makes more edges local than the
    agents' own numbering (a ring with random chords is local as numbered, and reverse Cuthill-McKee scatters it:
    15 % slower measured); else the identity (None). It depends on the graph alone, never on the number of seeds
    or the layout, so a seed's numbers do not either. A graph numbered near by construction (`Graph.near`: a chunked
    small-world or geometric graph, where reverse Cuthill-McKee never did better) keeps its numbering without the
    search, which takes the whole graph (2.3 s at a million agents); the ranks' blocks are then its own numbering's."""
    return per_run(ctx, "order", lambda: _rcm_order(ctx.network.base))


def _local_fraction(edges: np.ndarray, row_of: np.ndarray) -> float:
    """Fraction of the edges whose two ends sit at most NEARBY_ROWS rows apart when agent i is in row row_of[i]."""
    return float(np.mean(np.abs(row_of[edges[:, 0]] - row_of[edges[:, 1]]) <= NEARBY_ROWS))


def _rcm_order(graph):
    if graph.n_nodes < RELABEL_MIN_AGENTS or graph.n_edges == 0 or getattr(graph, "near", False):
        return None
    from scipy.sparse.csgraph import reverse_cuthill_mckee

    order = np.asarray(reverse_cuthill_mckee(graph.laplacian_sparse().tocsr(), symmetric_mode=True), dtype=np.int64)
    inverse = np.empty_like(order)
    inverse[order] = np.arange(graph.n_nodes)
    if _local_fraction(graph.edges, inverse) <= _local_fraction(graph.edges, np.arange(graph.n_nodes)):
        return None
    return order, inverse


def storage_graph(ctx):
    """CSR neighbour lists of the base graph in storage rows (`storage_order`), with the original edge ids, and
    the agent of every row."""

    def build():
        order = storage_order(ctx)
        if order is None:
            return (*graph_arrays(ctx), np.arange(ctx.network.n_nodes, dtype=np.int64))
        return (*csr_adjacency(order[1][ctx.network.base.edges], ctx.network.n_nodes), order[0])

    return per_run(ctx, "storage_csr", build)
