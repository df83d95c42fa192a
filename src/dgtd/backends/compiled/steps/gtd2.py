"""Centralised GTD2, its one learner's step: `dgtd.algorithms.gtd2.GTD2.update`, line for line; TDC's step
(`dgtd.backends.compiled.steps.tdc`) differs in the value terms only, and shares `centralised`."""

from __future__ import annotations

from typing import NamedTuple

from numba import njit

from dgtd.backends.compiled.step import aux_step, phi_axpy, phi_dot, register, transition

W, THETA = 0, 1  # its own arrays; it sends nothing
DW, DTHETA = 0, 1  # its work rows: the terms of the N transitions, summed


class GTD2Params(NamedTuple):
    eta: float  # beta_k = eta alpha0 (alpha_k / alpha0)^timescale (`dgtd.algorithms.gtd2.GTDConfig`)
    alpha0: float
    timescale: float


@njit(cache=True, inline="always")
def centralised(tdc, p, own, sums, inbox, work, x, feat, b, alpha, q):
    """The one learner's step of GTD2 (``tdc`` False) or TDC (True): the terms of the N transitions, averaged."""
    at, N = inbox.at, x.r.shape[1]
    for f in range(q):
        sums[b, 0, f] += own[W, b, 0, f]
        work[DW, at, f] = 0.0
        work[DTHETA, at, f] = 0.0
    for o in range(N):
        s, sn, r, ratio, gamma = transition(x, o)
        delta = r + gamma * phi_dot(feat, sn, own, (W, b, 0), q) - phi_dot(feat, s, own, (W, b, 0), q)
        phi_theta = phi_dot(feat, s, own, (THETA, b, 0), q)
        # value terms: GTD2's ratio phi^T theta (phi - gamma phi'), TDC's ratio (delta phi - gamma phi' phi^T theta)
        phi_axpy(feat, s, ratio * (delta if tdc else phi_theta), work, (DW, at), q)
        phi_axpy(feat, sn, -gamma * (ratio * phi_theta), work, (DW, at), q)
        phi_axpy(feat, s, ratio * delta - phi_theta, work, (DTHETA, at), q)  # (ratio delta - phi^T theta) phi
    beta_k = aux_step(alpha, p.eta, p.alpha0, p.timescale)  # the auxiliary step (`GTDConfig.aux_step`)
    for f in range(q):
        own[W, b, 0, f] += alpha * (work[DW, at, f] / N)
        own[THETA, b, 0, f] += beta_k * (work[DTHETA, at, f] / N)


@register("gtd2", GTD2Params, own=("w", "theta"), work=2)
@njit(cache=True, inline="always")
def gtd2_step(p, own, sums, inbox, out, work, x, feat, b, i, agent, alpha, q):
    """w += alpha_k (1/N) sum_i ratio_i (phi_i - gamma phi'_i) phi_i^T theta; theta += beta_k (1/N) sum_i (ratio_i
    delta_i - phi_i^T theta) phi_i."""
    centralised(False, p, own, sums, inbox, work, x, feat, b, alpha, q)
