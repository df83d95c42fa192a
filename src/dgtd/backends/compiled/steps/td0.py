"""Centralised TD(0), its one learner's step: `dgtd.algorithms.td0.TD0.update`, line for line."""

from __future__ import annotations

from typing import NamedTuple

from numba import njit

from dgtd.backends.compiled.step import phi_axpy, phi_dot, register, transition

W = 0  # its own array; it sends nothing
DW = 0  # its work row: the terms of the N transitions, summed


class TD0Params(NamedTuple):
    """No parameters beyond the step size: a type of its own, by which the driver finds the step."""


@register("td0", TD0Params, own=("w",), work=1)
@njit(cache=True, inline="always")
def td0_step(p, own, sums, inbox, out, work, x, feat, b, i, agent, alpha, q):
    """w += alpha_k (1/N) sum_i ratio_i delta_i phi_i over the N transitions the agents observed."""
    at, N = inbox.at, x.r.shape[1]
    for f in range(q):
        sums[b, 0, f] += own[W, b, 0, f]
        work[DW, at, f] = 0.0
    for o in range(N):
        s, sn, r, ratio, gamma = transition(x, o)
        delta = r + gamma * phi_dot(feat, sn, own, (W, b, 0), q) - phi_dot(feat, s, own, (W, b, 0), q)
        phi_axpy(feat, s, ratio * delta, work, (DW, at), q)  # ratio_i delta_i phi_i
    for f in range(q):
        own[W, b, 0, f] += alpha * (work[DW, at, f] / N)  # the mean over the N transitions
