"""Consensus TD(0) for one agent: `dgtd.algorithms.consensus_td0.ConsensusTD0.update`, line for line."""

from __future__ import annotations

from typing import NamedTuple

from numba import njit

from dgtd.backends.compiled.channel import metropolis
from dgtd.backends.compiled.step import phi_axpy, phi_dot, register, transition

W = 0  # its message


class ConsensusParams(NamedTuple):
    """No parameters beyond the step size: a type of its own, by which the driver finds the step."""


@register("consensus-td0", ConsensusParams, degrees=True)
@njit(cache=True, inline="always")
def consensus_td0_step(p, own, sums, inbox, out, work, x, feat, b, i, agent, alpha, q):
    """w_i(k+1) = w_i - (L_W(k) w)_i + alpha_k ratio delta_i phi_i, with sum_j W_ij w_j = w_i - (L_W(k) w)_i."""
    sent, at = inbox.sent, inbox.at
    s, sn, r, ratio, gamma = transition(x, agent)
    metropolis(inbox, W, b, i)  # (L_W(k) w)_i
    delta = r + gamma * phi_dot(feat, sn, sent, (W, b, i), q) - phi_dot(feat, s, sent, (W, b, i), q)
    for f in range(q):
        sums[b, i, f] += sent[W, b, i, f]
        out[W, b, i, f] = sent[W, b, i, f] - inbox.sums[W, at, f]
    phi_axpy(feat, s, alpha * (ratio * delta), out, (W, b, i), q)
