"""Algorithm 1 (section 7 of the paper) for one agent: `dgtd.algorithms.dgtd.DGTD.update`, line for line.

Its neighbour sums, the TD terms, then for each feature the lines of `dgtd.algorithms.dgtd.direction` and
`DGTD.update` in the same order and with the same names, as plain numba expressions (LLVM vectorises the loop over
features; no fastmath, so every process gets the same bits). What the agent sends (`DGTD.sends`): w and v + mu, of
which the neighbours form (L(k) w)_i and (L(k) (v + mu))_i = (L(k) v)_i + (L(k) mu)_i.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from dgtd.backends.compiled.channel import laplacian
from dgtd.backends.compiled.step import clip, phi_dot, phi_value, register, transition

THETA, V, MU = 0, 1, 2  # its own arrays
W, VMU = 0, 1  # its messages (`DGTD.messages`)


class DGTDParams(NamedTuple):
    kappa: float
    rho: float
    b_theta: float  # the projection boxes' half-widths (Algorithm 1 line 9)
    b_v: float
    b_mu: float
    b_w: float


def params(algorithm, ctx) -> DGTDParams:
    boxes = (np.inf,) * 4 if algorithm.boxes is None else algorithm.boxes
    return DGTDParams(float(algorithm.kappa), float(algorithm.rho), *(float(x) for x in boxes))


@register("dgtd", DGTDParams, params, own=("theta", "v", "mu"))
@njit(cache=True, inline="always")
def dgtd_step(p, own, sums, inbox, out, work, x, feat, b, i, agent, alpha, q):
    """Algorithm 1 lines 7-9 for agent i of seed b at step k: theta, v, mu and the running sum of w are updated in
    place; w and v + mu of step k are the messages it sent, and those of step k + 1 go out."""
    sent, at = inbox.sent, inbox.at
    s, sn, r, ratio, gamma = transition(x, agent)
    laplacian(inbox, W, b, i)  # (L(k) w)_i
    laplacian(inbox, VMU, b, i)  # (L(k) v)_i + (L(k) mu)_i = (L(k) (v + mu))_i
    L = inbox.sums  # L[W, at] and L[VMU, at]
    phi_theta = phi_dot(feat, s, own, (THETA, b, i), q)
    phi_w, phin_w = phi_dot(feat, s, sent, (W, b, i), q), phi_dot(feat, sn, sent, (W, b, i), q)
    # Line 7's theta direction is phi c_theta; line 8's TD part of w is ratio phi^T theta (phi - gamma phi')
    c_theta = phi_theta + ratio * (phi_w - gamma * phin_w - r)
    ratio_phi_theta = ratio * phi_theta
    for f in range(q):
        w = sent[W, b, i, f]
        sums[b, i, f] += w  # the running sum of w_k behind the averaged iterates
        v, mu = own[V, b, i, f], own[MU, b, i, f]
        # Line 7, v: g_v = v - (L(k) w)_i
        v_new = clip(v - alpha * (v - L[W, at, f]), p.b_v)
        # Line 8, mu: g_mu = -(L(k) w)_i + rho mu
        mu_new = clip(mu - alpha * (-L[W, at, f] + p.rho * mu), p.b_mu)
        own[V, b, i, f] = v_new
        own[MU, b, i, f] = mu_new
        out[VMU, b, i, f] = v_new + mu_new
        # Line 8, w: g_w = ratio phi^T theta (phi - gamma phi') - (L v)_i - (L mu)_i - kappa (L w)_i - rho w
        phi, phi_next = (0.0, 0.0) if feat.sparse else (feat.Phi[s, f], feat.Phi[sn, f])
        g_w = ratio_phi_theta * (phi - gamma * phi_next) - L[VMU, at, f] - p.kappa * L[W, at, f] - p.rho * w
        out[W, b, i, f] = clip(w + alpha * g_w, p.b_w)
        # Line 7, theta: g_theta = phi (phi^T theta + ratio (phi^T w - gamma phi'^T w - r)) = phi c_theta
        own[THETA, b, i, f] = clip(own[THETA, b, i, f] - alpha * (phi * c_theta), p.b_theta)
    if feat.sparse:  # the loop took phi = phi' = 0; w and theta again where phi(s) or phi(s') is not zero
        for k in range(feat.ptr[s], feat.ptr[s + 1]):
            f = feat.idx[k]
            _sparse_feature(
                p,
                own,
                sent,
                out,
                L,
                at,
                b,
                i,
                f,
                feat.val[k],
                phi_value(feat, sn, f),
                alpha,
                gamma,
                ratio_phi_theta,
                c_theta,
            )
        for k in range(feat.ptr[sn], feat.ptr[sn + 1]):
            f = feat.idx[k]
            if phi_value(feat, s, f) == 0.0:  # not done above
                _sparse_feature(
                    p, own, sent, out, L, at, b, i, f, 0.0, feat.val[k], alpha, gamma, ratio_phi_theta, c_theta
                )


@njit(cache=True, inline="always")
def _sparse_feature(p, own, sent, out, L, at, b, i, f, phi, phi_next, alpha, gamma, ratio_phi_theta, c_theta):
    """Feature f of w and theta, the lines of `dgtd_step`'s loop, with phi_f(s) and phi_f(s') not both zero."""
    w = sent[W, b, i, f]
    g_w = ratio_phi_theta * (phi - gamma * phi_next) - L[VMU, at, f] - p.kappa * L[W, at, f] - p.rho * w
    out[W, b, i, f] = clip(w + alpha * g_w, p.b_w)
    own[THETA, b, i, f] = clip(own[THETA, b, i, f] - alpha * (phi * c_theta), p.b_theta)
