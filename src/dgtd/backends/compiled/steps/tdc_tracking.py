"""TDC with gradient tracking for one agent: `dgtd.algorithms.tdc_tracking.TDCTracking.update`, line for line."""

from __future__ import annotations

from typing import NamedTuple

from numba import njit

from dgtd.backends.compiled.step import aux_step, phi_axpy, phi_dot, phi_times, register, transition
from dgtd.backends.compiled.steps.td_tracking import track

THETA, G = 0, 1  # its own arrays: TDC's auxiliary vector, the last local direction
W = 0  # its messages: w, and z (`dgtd.backends.compiled.steps.td_tracking.track`)
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
    sent, at = inbox.sent, inbox.at
    s, sn, r, ratio, gamma = transition(x, agent)
    delta = r + gamma * phi_dot(feat, sn, sent, (W, b, i), q) - phi_dot(feat, s, sent, (W, b, i), q)
    phi_theta = phi_dot(feat, s, own, (THETA, b, i), q)
    # TDC's value direction g_i(k) = ratio delta phi - gamma ratio phi^T theta phi'
    phi_times(feat, s, ratio * delta, work, (G_NEW, at), q)
    phi_axpy(feat, sn, -gamma * (ratio * phi_theta), work, (G_NEW, at), q)
    track(own, G, sums, inbox, out, work[G_NEW], b, i, alpha, q)
    # theta_i's own TDC step: beta_k (ratio delta - phi^T theta) phi
    phi_axpy(
        feat, s, aux_step(alpha, p.eta, p.alpha0, p.timescale) * (ratio * delta - phi_theta), own, (THETA, b, i), q
    )
