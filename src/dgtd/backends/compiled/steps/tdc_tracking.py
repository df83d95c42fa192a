"""TDC with gradient tracking for one agent: `dgtd.algorithms.tdc_tracking.TDCTracking.update`, line for line."""

from __future__ import annotations

from typing import NamedTuple

from numba import njit

from dgtd.backends.compiled.channel import metropolis
from dgtd.backends.compiled.step import aux_step, phi_axpy, phi_dot, phi_times, register, transition

THETA, G = 0, 1  # its own arrays: TDC's auxiliary vector, the last local direction
W, Z = 0, 1  # its messages
G_NEW = 0  # its work row: this step's local direction


class TDCTrackingParams(NamedTuple):
    eta: float  # beta_k = eta alpha0 (alpha_k / alpha0)^timescale (`dgtd.algorithms.gtd2.GTDConfig`)
    alpha0: float
    timescale: float


@register("tdc-tracking", TDCTrackingParams, own=("theta", "g"), degrees=True, work=1)
@njit(cache=True, inline="always")
def tdc_tracking_step(p, own, sums, inbox, out, work, x, feat, b, i, agent, alpha, q):
    """g_i = ratio (delta phi - gamma phi' phi^T theta_i); z_i <- z_i - (L_W z)_i + g_i - g_i(k-1); w_i <- w_i -
    (L_W w)_i + alpha_k z_i; theta_i += beta_k (ratio delta - phi^T theta_i) phi."""
    sent, L, at = inbox.sent, inbox.sums, inbox.at
    s, sn, r, ratio, gamma = transition(x, agent)
    metropolis(inbox, W, b, i)  # (L_W(k) w)_i
    metropolis(inbox, Z, b, i)  # (L_W(k) z)_i
    delta = r + gamma * phi_dot(feat, sn, sent, (W, b, i), q) - phi_dot(feat, s, sent, (W, b, i), q)
    phi_theta = phi_dot(feat, s, own, (THETA, b, i), q)
    # TDC's value direction g_i(k) = ratio delta phi - gamma ratio phi^T theta phi'
    phi_times(feat, s, ratio * delta, work, (G_NEW, at), q)
    phi_axpy(feat, sn, -gamma * (ratio * phi_theta), work, (G_NEW, at), q)
    for f in range(q):
        sums[b, i, f] += sent[W, b, i, f]
        g = work[G_NEW, at, f]
        z_new = sent[Z, b, i, f] - L[Z, at, f] + g - own[G, b, i, f]  # the tracker z_i(k)
        out[W, b, i, f] = sent[W, b, i, f] - L[W, at, f] + alpha * z_new
        out[Z, b, i, f] = z_new
        own[G, b, i, f] = g
    # theta_i's own TDC step: beta_k (ratio delta - phi^T theta) phi
    phi_axpy(feat, s, aux_step(alpha, p.eta, p.alpha0, p.timescale) * (ratio * delta - phi_theta), own, (THETA, b, i),
             q)
