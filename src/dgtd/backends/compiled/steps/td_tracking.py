"""TD(0) with gradient tracking for one agent: `dgtd.algorithms.td_tracking.TDTracking.update`, line for line."""

from __future__ import annotations

from typing import NamedTuple

from numba import njit

from dgtd.backends.compiled.channel import metropolis
from dgtd.backends.compiled.step import phi_dot, phi_times, register, transition

G = 0  # its own array: the last local direction
W, Z = 0, 1  # its messages
G_NEW = 0  # its work row: this step's local direction


class TrackingParams(NamedTuple):
    """No parameters beyond the step size: a type of its own, by which the driver finds the step."""


@register("td-tracking", TrackingParams, own=("g",), degrees=True, work=1)
@njit(cache=True, inline="always")
def td_tracking_step(p, own, sums, inbox, out, work, x, feat, b, i, agent, alpha, q):
    """g_i = ratio delta_i phi_i; z_i <- z_i - (L_W z)_i + g_i - g_i(k-1); w_i <- w_i - (L_W w)_i + alpha_k z_i."""
    sent, at = inbox.sent, inbox.at
    s, sn, r, ratio, gamma = transition(x, agent)
    delta = r + gamma * phi_dot(feat, sn, sent, (W, b, i), q) - phi_dot(feat, s, sent, (W, b, i), q)
    phi_times(feat, s, ratio * delta, work, (G_NEW, at), q)  # g_i(k) = ratio delta phi
    track(own, G, sums, inbox, out, work[G_NEW], b, i, alpha, q)


@njit(cache=True, inline="always")
def track(own, g_row, sums, inbox, out, g, b, i, alpha, q):
    """Gradient tracking for agent i (`dgtd.algorithms.td_tracking.track`), with this step's local direction in row
    g[inbox.at] and the last in own[g_row]: z_i(k) = z_i - (L_W z)_i + g_i(k) - g_i(k-1), w_i(k+1) = w_i - (L_W w)_i
    + alpha_k z_i(k); the running sum of w and g_i(k) kept."""
    metropolis(inbox, W, b, i)  # (L_W(k) w)_i
    metropolis(inbox, Z, b, i)  # (L_W(k) z)_i
    sent, L, at = inbox.sent, inbox.sums, inbox.at
    for f in range(q):
        sums[b, i, f] += sent[W, b, i, f]
        z_new = sent[Z, b, i, f] - L[Z, at, f] + g[at, f] - own[g_row, b, i, f]  # the tracker z_i(k)
        out[W, b, i, f] = sent[W, b, i, f] - L[W, at, f] + alpha * z_new
        out[Z, b, i, f] = z_new
        own[g_row, b, i, f] = g[at, f]
