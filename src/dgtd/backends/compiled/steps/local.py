"""Local GTD2 for one agent, on its own reward: `dgtd.algorithms.local.Local.update`, line for line."""

from __future__ import annotations

from typing import NamedTuple

from numba import njit

from dgtd.backends.compiled.step import aux_step, phi_axpy, phi_dot, register, transition

W, THETA = 0, 1  # its own arrays; it sends nothing


class LocalParams(NamedTuple):
    eta: float  # beta_k = eta alpha0 (alpha_k / alpha0)^timescale (`dgtd.algorithms.gtd2.GTDConfig`)
    alpha0: float
    timescale: float


@register("local", LocalParams, own=("w", "theta"))
@njit(cache=True, inline="always")
def local_step(p, own, sums, inbox, out, work, x, feat, b, i, agent, alpha, q):
    """GTD2 on agent i's own sample: w += alpha ratio phi^T theta (phi - gamma phi'); theta += beta_k (ratio delta -
    phi^T theta) phi; both from the values at step k (agent i reads only its own rows: in place is the Jacobi step)."""
    s, sn, r, ratio, gamma = transition(x, agent)
    delta = r + gamma * phi_dot(feat, sn, own, (W, b, i), q) - phi_dot(feat, s, own, (W, b, i), q)
    phi_theta = phi_dot(feat, s, own, (THETA, b, i), q)
    for f in range(q):
        sums[b, i, f] += own[W, b, i, f]
    c = alpha * (ratio * phi_theta)  # w: alpha ratio phi^T theta (phi - gamma phi')
    phi_axpy(feat, s, c, own, (W, b, i), q)
    phi_axpy(feat, sn, -gamma * c, own, (W, b, i), q)
    beta_k = aux_step(alpha, p.eta, p.alpha0, p.timescale)  # theta: beta_k (ratio delta - phi^T theta) phi
    phi_axpy(feat, s, beta_k * (ratio * delta - phi_theta), own, (THETA, b, i), q)
