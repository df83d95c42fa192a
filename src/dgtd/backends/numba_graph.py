"""Graphs for the compiled kernels: CSR neighbour lists with edge ids, the storage order of the agents, and
prefetching of neighbours' rows."""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic


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


def storage_order(ctx):
    """(order, inverse) of the agents in the DGTD kernels' arrays: row r holds agent order[r], agent i sits in row
    inverse[i]. From RELABEL_MIN_AGENTS agents on, a reverse Cuthill-McKee ordering puts neighbours in nearby
    rows, so that the rows an agent reads are mostly in cache already; below it, the identity (None). It depends
    on the graph alone, never on the number of seeds or the layout, so a seed's numbers do not either."""
    return per_run(ctx, "order", lambda: _rcm_order(ctx.network.base))


def _rcm_order(graph):
    if graph.n_nodes < RELABEL_MIN_AGENTS or graph.n_edges == 0:
        return None
    from scipy.sparse.csgraph import reverse_cuthill_mckee

    order = np.asarray(reverse_cuthill_mckee(graph.laplacian_sparse().tocsr(), symmetric_mode=True), dtype=np.int64)
    inverse = np.empty_like(order)
    inverse[order] = np.arange(graph.n_nodes)
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


@intrinsic
def _prefetch(typingctx, arr, i0, i1, i2):
    """Ask the caches for element [i0, i1, i2] of a 3-D array (a hint: no effect on any result)."""
    sig = types.void(arr, i0, i1, i2)

    def codegen(context, builder, signature, args):
        aryty = signature.args[0]
        ary = context.make_array(aryty)(context, builder, args[0])
        ptr = cgutils.get_item_pointer(context, builder, aryty, ary, args[1:], wraparound=False)
        i32 = ir.IntType(32)
        fnty = ir.FunctionType(ir.VoidType(), [ptr.type, i32, i32, i32])
        fn = cgutils.get_or_insert_function(builder.module, fnty, "llvm.prefetch.p0")
        builder.call(fn, [ptr, ir.Constant(i32, 0), ir.Constant(i32, 3), ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return sig, codegen


@njit(cache=True, inline="always")
def _prefetch_rows(Z, b, i, up, ub, indptr, nbr, eid):
    """Prefetch the packed rows of agent i's neighbours that are up: on large graphs they are scattered in
    memory, and the next agent's rows arrive while this agent computes."""
    m = Z.shape[2]
    for p in range(indptr[i], indptr[i + 1]):
        if up[ub, eid[p]]:
            j = nbr[p]
            for f in range(0, m, 8):  # one 64-byte line holds 8 doubles
                _prefetch(Z, b, j, f)
