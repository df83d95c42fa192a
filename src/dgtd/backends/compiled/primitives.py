"""Generic compiled primitives the kernels of `dgtd.backends.compiled.kernels` share: no algorithm's maths.

Plain numba loops; each sums in a fixed order (no fastmath), so a kernel's results are the same bits in every
process. Elements are indexed directly (X[b, i, f]) rather than through row views where a kernel runs in parallel
(numba counts references to every view atomically). Also the Python-side helpers that hand arrays to kernels.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from dgtd.backends.compiled.graph import graph_arrays
from dgtd.backends.compiled.sampling import up_mask
from dgtd.samples import Block


@njit(cache=True, inline="always")
def add_rows(x, b, total):
    """total[b] += x[b] over all rows and features: the running sum of the estimates."""
    for e in range(x.shape[1]):
        for f in range(x.shape[2]):
            total[b, e, f] += x[b, e, f]


@njit(cache=True, inline="always")
def feature_dot(Phi, s, x, b, e):
    """phi(s)^T x[b, e], summed in feature order."""
    acc = 0.0
    for f in range(x.shape[2]):
        acc += Phi[s, f] * x[b, e, f]
    return acc


@njit(cache=True, inline="always")
def transition(s_blk, a_blk, sn_blk, ratio_tab, t, b, i, N):
    """(s, s', ratio) of agent i's transition at step t of seed b: its own, or the one all agents share."""
    o = i if s_blk.shape[2] == N else 0
    s = s_blk[t, b, o]
    return s, sn_blk[t, b, o], ratio_tab[s, a_blk[t, b, o]]


@njit(cache=True, inline="always")
def discount(gamma, cont, s, sn):
    """gamma(s, s') = gamma c(s) c(s'): 0 into and out of an episodic task's terminal states (`Block.sample`)."""
    return gamma * cont[s] * cont[sn]


@njit(cache=True, inline="always")
def aux_step(alpha, eta, alpha0, timescale):
    """The auxiliary step beta_k of the GTD learners (`dgtd.algorithms.gtd2.aux_step`, the same expression)."""
    return eta * alpha if timescale == 1.0 else eta * alpha0 * (alpha / alpha0) ** timescale


def aux_params(algorithm) -> tuple:
    """(eta, alpha0, timescale) of a GTD learner, for `aux_step`."""
    return float(algorithm.eta), float(algorithm.alpha0), float(algorithm.timescale)


@njit(cache=True, inline="always")
def td_error(Phi, s, sn, r, gamma, w, b, e):
    """delta = r + gamma phi(s')^T w[b, e] - phi(s)^T w[b, e] (`dgtd.algorithms.base.td_error`)."""
    return r + gamma * feature_dot(Phi, sn, w, b, e) - feature_dot(Phi, s, w, b, e)


@njit(cache=True, inline="always")
def degrees(up, t, b, has_up, indptr, eid, deg):
    """deg[i] = agent i's number of links up at step t (all its edges on a fixed graph)."""
    for i in range(deg.shape[0]):
        d = 0
        for p in range(indptr[i], indptr[i + 1]):
            if (not has_up) or up[t, b, eid[p]]:
                d += 1
        deg[i] = d


@njit(cache=True)
def laplacian_rows(X, b, up, t, has_up, indptr, nbr, eid, metropolis, deg, out):
    """out[i] = sum over links {i, j} up at step t of c_ij (X[b, i] - X[b, j]): c_ij = 1 (the Laplacian L(k)) or,
    with ``metropolis``, 1 / (1 + max(d_i, d_j)) from the degrees ``deg`` (`degrees`), the Metropolis Laplacian."""
    N, q = out.shape
    for i in range(N):
        for f in range(q):
            out[i, f] = 0.0
        for p in range(indptr[i], indptr[i + 1]):
            if (not has_up) or up[t, b, eid[p]]:
                j = nbr[p]
                c = 1.0 / (1.0 + max(deg[i], deg[j])) if metropolis else 1.0
                for f in range(q):
                    out[i, f] += c * (X[b, i, f] - X[b, j, f])


def f64(x) -> np.ndarray:
    """A C-contiguous float64 copy: kernels update their arrays in place."""
    return np.array(x, dtype=np.float64, order="C")


def model_arrays(ctx, blk: Block) -> tuple:
    """(s, a, s_next, r) of the block and the problem's (Phi, ratio table, gamma, continuing flags c): what every
    kernel reads; a transition s -> s' discounts by gamma c(s) c(s') (`discount`)."""
    Phi, ratio = rows_of(ctx, blk)
    return blk.s, blk.a, blk.s_next, blk.r, readonly(Phi), readonly(ratio), float(ctx.gamma), continuing_flags(ctx, blk)


def rows_of(ctx, blk) -> tuple:
    """(Phi, ratio table) the block's indices point into: its own rows (`SampleTable`), else the model's; a `Draws`
    (samples drawn inside the kernel from the model) has no rows of its own."""
    table = getattr(blk, "table", None)
    return (ctx.Phi, ctx.ratio) if table is None else (table.phi, table.ratio)


def readonly(x) -> np.ndarray:
    """A C-contiguous float64 read-only view, as the model's arrays are: numba compiles a kernel once per array
    type, and a writable array is another type, so a block's own rows would otherwise cost a second compilation."""
    view = np.ascontiguousarray(x, np.float64).view()
    view.setflags(write=False)
    return view


def continuing_flags(ctx, blk: Block | None = None) -> np.ndarray:
    """c of the rows the block's indices point into: 0 at an episodic task's terminal states (or, for a block with its
    own `SampleTable`, at the next state of a transition that ended an episode), 1 elsewhere."""
    table = getattr(blk, "table", None)  # a `Draws` (samples drawn inside the kernel) has none
    if table is not None:
        return np.ascontiguousarray(table.continuing, np.float64)
    return np.ones(ctx.Phi.shape[0]) if ctx.continuing is None else np.ascontiguousarray(ctx.continuing, np.float64)


def link_arrays(ctx, blk: Block) -> tuple:
    """(up mask, CSR indptr, neighbours, edge ids) of the block's links."""
    return (up_mask(blk), *graph_arrays(ctx))
