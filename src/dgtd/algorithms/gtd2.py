"""GTD2 (Sutton, Maei, Precup, Bhatnagar, Silver, Szepesvari, Wiewiora, ICML 2009), as pure functions.

In the paper's notation the value weights are theta and the auxiliary vector is w; dgtd's glossary (the
one of the DGTD paper, where theta plays the auxiliary's role) swaps them: here ``w`` are the value weights
and ``theta`` the auxiliary vector, which tracks M^-1 (b - A w) exactly as DGTD's theta does. With the
importance ratio (off-policy GTD2, Maei 2011), at each sample:

    w     <- w     + alpha_k ratio (phi - gamma phi') (phi^T theta)           (the paper's theta update)
    theta <- theta + eta alpha_k (ratio delta - phi^T theta) phi              (the paper's w update)

with delta = r + gamma phi'^T w - phi^T w and the paper's two step sizes alpha, beta = eta alpha. The mean
path is w' = A^T theta, theta' = eta (b - A w - M theta). The centralised learner averages these terms over
the N transitions the agents observed (see `dgtd.algorithms.td0`); `local` applies them per agent.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from dgtd.algorithms.stepsizes import check_schedule
from dgtd.algorithms.td0 import agent_mean, dot, td_error
from dgtd.errors import DgtdInputError


class GTDState(NamedTuple):
    w: np.ndarray  # (B, 1, q) centralised, (B, N, q) local
    theta: np.ndarray


def check_eta(eta: float) -> None:
    if not (np.isfinite(eta) and eta > 0):
        raise DgtdInputError(f"eta (auxiliary step size / main step size) must be positive, got {eta}")


@dataclass(frozen=True)
class GTDConfig:
    """Fields shared by the centralised two-timescale gradient-TD learners (GTD2, TDC).

    - ``alpha0``, ``beta``, ``schedule``: the value step sizes alpha_k (see `dgtd.algorithms.stepsizes`).
    - ``eta``: the auxiliary step size is eta alpha_k (Sutton et al. 2009's beta = eta alpha).
    """

    alpha0: float = 0.1
    beta: float = 1.0
    schedule: str = "sqrt"
    eta: float = 1.0

    vectors_per_direction = 0

    def __post_init__(self):
        check_schedule(self.schedule, self.alpha0, self.beta)
        check_eta(self.eta)

    def init(self, n_seeds: int, n_agents: int, n_features: int) -> GTDState:
        z = np.zeros((n_seeds, 1, n_features))
        return GTDState(z, z.copy())

    @staticmethod
    def estimate(state: GTDState) -> np.ndarray:
        return state.w


@dataclass(frozen=True)
class GTD2(GTDConfig):
    """Centralised GTD2 on the average reward; fields as `GTDConfig`."""

    name = "gtd2"


def theta_terms(w, theta, phi, phi_next, r, ratio, gamma: float) -> np.ndarray:
    """Per-agent auxiliary terms (ratio_i delta_i - phi_i^T theta) phi_i, shape (B, N, q)."""
    delta = td_error(w, phi, phi_next, r, gamma)
    return (np.broadcast_to(ratio, delta.shape) * delta - dot(phi, theta))[..., None] * phi


def w_terms(theta, phi, phi_next, ratio, gamma: float) -> np.ndarray:
    """Per-agent GTD2 value terms ratio_i (phi_i - gamma phi'_i) (phi_i^T theta), shape (B, N or 1, q)."""
    return (ratio * dot(phi, theta))[..., None] * (phi - gamma * phi_next)


def increments(state: GTDState, phi, phi_next, r, ratio, gamma: float, central: bool = True):
    """(dw, dtheta) of GTD2: averaged over the agents' transitions (central) or per agent (local)."""
    N = r.shape[1]
    dw = w_terms(state.theta, phi, phi_next, ratio, gamma)
    dtheta = theta_terms(state.w, state.theta, phi, phi_next, r, ratio, gamma)
    if central:
        return agent_mean(dw, N), agent_mean(dtheta, N)
    shape = (r.shape[0], N, phi.shape[2])
    return np.broadcast_to(dw, shape), dtheta


def update(state: GTDState, phi, phi_next, r, ratio, alpha: float, eta: float, gamma: float,
           central: bool = True) -> GTDState:
    """One GTD2 step: both updates use the values at step k."""
    dw, dtheta = increments(state, phi, phi_next, r, ratio, gamma, central)
    return GTDState(state.w + alpha * dw, state.theta + eta * alpha * dtheta)
