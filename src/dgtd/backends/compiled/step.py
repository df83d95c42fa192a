"""What a compiled per-agent step is given, and how the driver finds it.

An algorithm's compiled part is one function, its per-agent step: the lines of its ``update`` for one agent (or, for
a centralised learner, for the one learner), registered with `register`::

    W = 0  # its one message

    @register("consensus-td0", ConsensusParams, degrees=True)
    @njit(cache=True, inline="always")
    def consensus_td0_step(p, own, sums, inbox, out, work, x, feat, b, i, agent, alpha, q): ...

- ``p``: the algorithm's own parameters, a NamedTuple of a type of its own;
- ``own``: the state's arrays that are not sent, stacked (K, B, learners, q) in the order ``register`` names them,
  updated in place in rows [k, b, i];
- ``sums``: the running sum of the estimates (B, learners, q), to which the step adds its estimate at step k (as the
  reference's ``w_sum += estimate(state)`` before ``update``);
- ``inbox``: what agent i heard (`dgtd.backends.compiled.channel.Inbox`: the messages of step k, stacked (M, B, N, q)
  in the order of the algorithm's ``messages``, and their ``laplacian``, ``metropolis`` and ``total``), and ``out``:
  the messages it sends at step k + 1, written in rows [m, b, i]: the driver double-buffers them, so every agent
  reads its neighbours' values of step k;
- ``work``: the scratch rows the step asked for (``register(..., work=K)``), (K, rows, q), row ``inbox.at`` its own (a
  centralised learner sums its N transitions' terms there);
- ``x``: the step's samples (`Samples`; `transition` gives an agent's), ``feat`` the features (`Features`; `phi_dot`
  and `phi_axpy` read dense or sparse rows alike);
- ``b``, ``i``, ``agent``: the seed, the storage row and the agent in it; ``alpha`` the step size; ``q`` the number
  of features (passed in: computed from a shape inside, LLVM cannot prove the feature loops' indices in range and
  leaves them scalar).

The state's arrays are stacked in one array (rather than a tuple of arrays) so that the parallel layout, which numba
cannot hand tuples of arrays, takes them as they are; each array is a contiguous block of its own, and a row's loops
vectorise as over separate arrays.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

from dgtd.backends.compiled.simd import dot


@dataclass(frozen=True)
class CompiledStep:
    """A registered per-agent step: the function, the type of its parameters, how to build them from the algorithm
    as it runs (``params(algorithm, ctx)``), the names of the state's arrays it keeps in ``own`` (in that order),
    whether its inbox needs every agent's count of messages heard (the Metropolis weights do), and how many scratch
    rows it works in."""

    step: Callable
    params_type: type
    params: Callable
    own: tuple[str, ...] = ()
    degrees: bool = False
    work: int = 0


STEPS: dict[str, CompiledStep] = {}
"""Algorithm name -> its compiled step."""


def register(
    name: str,
    params_type: type,
    params: Callable | None = None,
    *,
    own: tuple[str, ...] = (),
    degrees: bool = False,
    work: int = 0,
):
    """Register the decorated njit function as the compiled step of algorithm ``name``; ``params(algorithm, ctx)``
    builds its ``params_type`` (default: the algorithm's fields of the same names); ``own`` names the state's arrays
    that are not messages, in the order the step indexes them."""

    def build(algorithm, ctx):
        return params_type(*(float(getattr(algorithm, f)) for f in params_type._fields))

    def decorate(fn):
        STEPS[name] = CompiledStep(fn, params_type, params or build, tuple(own), degrees, work)
        return fn

    return decorate


class Samples(NamedTuple):
    """The samples of one step of one seed: observations s, a, s' (row ``row`` of (rows, n) arrays: n = N, or 1 on a
    shared trajectory), every agent's reward r (rows, N), the ratio table (S, A), the continuing flags c (S,) and
    gamma."""

    s: np.ndarray
    a: np.ndarray
    s_next: np.ndarray
    r: np.ndarray
    row: int
    ratio: np.ndarray
    continuing: np.ndarray
    gamma: float


@njit(cache=True, inline="always")
def transition(x, agent):
    """(s, s', r, ratio, gamma(s, s')) of ``agent``'s transition (its own observation, or the shared one):
    gamma(s, s') = gamma c(s) c(s') is 0 into and out of an episodic task's terminal states (`Block.sample`)."""
    o = agent if x.s.shape[1] == x.r.shape[1] else 0
    s, sn = x.s[x.row, o], x.s_next[x.row, o]
    return s, sn, x.r[x.row, agent], x.ratio[s, x.a[x.row, o]], x.gamma * x.continuing[s] * x.continuing[sn]


class Features(NamedTuple):
    """The features the observations index: dense rows ``Phi`` (S, q), or, where ``sparse``, only the CSR rows
    (``ptr``, ``idx``, ``val``) of their nonzero entries (``Phi`` is then a row of zeros)."""

    Phi: np.ndarray
    sparse: bool
    ptr: np.ndarray
    idx: np.ndarray
    val: np.ndarray


@njit(cache=True, inline="always")
def phi_dot(feat, s, X, at, q):
    """phi(s)^T X[*at] (the row ``at``, a tuple of indices), in a fixed order (dense: `dot`; sparse: the nonzero
    features in increasing order)."""
    if feat.sparse:
        acc = 0.0
        for p in range(feat.ptr[s], feat.ptr[s + 1]):
            acc += feat.val[p] * X[at + (feat.idx[p],)]
        return acc
    return dot(feat.Phi, s, X, at, q)


@njit(cache=True, inline="always")
def phi_axpy(feat, s, c, X, at, q):
    """X[*at] += c phi(s)."""
    if feat.sparse:
        for p in range(feat.ptr[s], feat.ptr[s + 1]):
            X[at + (feat.idx[p],)] += c * feat.val[p]
    else:
        for f in range(q):
            X[at + (f,)] += c * feat.Phi[s, f]


@njit(cache=True, inline="always")
def phi_times(feat, s, c, X, at, q):
    """X[*at] = c phi(s): a row of a step's work, which its loops over the features then read (a feature's phi_f(s)
    looked up inside such a loop would keep it from being vectorised)."""
    if feat.sparse:
        for f in range(q):
            X[at + (f,)] = 0.0
        for p in range(feat.ptr[s], feat.ptr[s + 1]):
            X[at + (feat.idx[p],)] = c * feat.val[p]
    else:
        for f in range(q):
            X[at + (f,)] = c * feat.Phi[s, f]


@njit(cache=True, inline="always")
def phi_value(feat, s, f):
    """phi_f(s) (where sparse, a search of the row's few nonzero features)."""
    if not feat.sparse:
        return feat.Phi[s, f]
    for p in range(feat.ptr[s], feat.ptr[s + 1]):
        if feat.idx[p] == f:
            return feat.val[p]
    return 0.0


@njit(cache=True, inline="always")
def clip(x, bound):
    """Projection onto [-bound, bound]; NaN stays NaN. Testing the inner result rather than x twice lets LLVM emit one
    min and one max instruction (a compare and a blend per test otherwise)."""
    inner = bound if x > bound else x
    return -bound if inner < -bound else inner


@njit(cache=True, inline="always")
def aux_step(alpha, eta, alpha0, timescale):
    """The auxiliary step beta_k of the GTD learners (`dgtd.algorithms.gtd2.aux_step`, the same expression)."""
    return eta * alpha if timescale == 1.0 else eta * alpha0 * (alpha / alpha0) ** timescale
