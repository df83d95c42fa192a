"""Primal-dual distributed TD for one agent: `dgtd.algorithms.pd_td.PDTD.update`, line for line."""

from __future__ import annotations

from typing import NamedTuple

from numba import njit

from dgtd.backends.compiled.channel import laplacian
from dgtd.backends.compiled.step import phi_axpy, phi_dot, register, transition

W, MU = 0, 1  # its messages


class PDTDParams(NamedTuple):
    eta: float


@register("pd-td", PDTDParams)
@njit(cache=True, inline="always")
def pd_td_step(p, own, sums, inbox, out, work, x, feat, b, i, agent, alpha, q):
    """w_i += alpha_k (ratio delta_i phi_i - eta (L(k) w)_i - eta (L(k) mu)_i); mu_i += alpha_k eta (L(k) w)_i."""
    sent, L, at = inbox.sent, inbox.sums, inbox.at
    s, sn, r, ratio, gamma = transition(x, agent)
    laplacian(inbox, W, b, i)  # (L(k) w)_i
    laplacian(inbox, MU, b, i)  # (L(k) mu)_i
    delta = r + gamma * phi_dot(feat, sn, sent, (W, b, i), q) - phi_dot(feat, s, sent, (W, b, i), q)
    for f in range(q):
        sums[b, i, f] += sent[W, b, i, f]
        out[W, b, i, f] = sent[W, b, i, f] + alpha * (-p.eta * L[W, at, f] - p.eta * L[MU, at, f])
        out[MU, b, i, f] = sent[MU, b, i, f] + alpha * p.eta * L[W, at, f]
    phi_axpy(feat, s, alpha * (ratio * delta), out, (W, b, i), q)
