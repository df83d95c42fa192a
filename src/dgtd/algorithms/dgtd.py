"""Algorithm 1 of the paper (`algo:DGTD`): the primal-dual distributed GTD method, as pure functions.

State is four arrays (B, N, q) for B seeds and N agents: theta, v, mu (minimised) and w (maximised) of the
Lagrangian eq. (Lagrangian2). One step uses one sample per agent and the Laplacian L(k) of the graph up at
step k, and every quantity on the right-hand side is taken at step k (Jacobi form, as in Algorithm 1).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from dgtd.algorithms.stepsizes import check_schedule
from dgtd.errors import DgtdInputError


@dataclass(frozen=True)
class DGTD:
    """Hyperparameters of Algorithm 1.

    - ``alpha0``, ``beta``, ``schedule``: step sizes alpha_k (see `dgtd.algorithms.stepsizes`).
    - ``kappa`` >= 0: weight of the consensus term -(kappa/2) w^T bar-L w of eq. (Lagrangian2).
    - ``rho`` >= 0: the regulariser (rho/2)|mu|^2 - (rho/2)|w|^2 described after `prop:convergence-DGTD2`.
    - ``box_scale``: projection boxes are C = B_{c + beta_c} with beta_c = (box_scale - 1) c and c the bounds of
      `lemma:bound-lemma3`; ``boxes`` (theta, v, mu, w half-widths) overrides them.
    """

    alpha0: float = 1.0
    beta: float = 1.0
    schedule: str = "sqrt"
    kappa: float = 1.0
    rho: float = 0.0
    box_scale: float = 2.0
    boxes: tuple[float, float, float, float] | None = None

    name = "dgtd"
    vectors_per_direction = 3  # w_i, v_i and mu_i go to each neighbour (Algorithm 1 lines 7-8)

    def init(self, n_seeds: int, n_agents: int, n_features: int) -> "DGTDState":
        return init(n_seeds, n_agents, n_features)

    @staticmethod
    def estimate(state: "DGTDState") -> np.ndarray:
        """The value-function weights the agents report: w, (B, N, q)."""
        return state.w

    def __post_init__(self):
        check_schedule(self.schedule, self.alpha0, self.beta)
        if not (np.isfinite(self.kappa) and self.kappa >= 0):
            raise DgtdInputError(f"kappa must be >= 0, got {self.kappa}")
        if not (np.isfinite(self.rho) and self.rho >= 0):
            raise DgtdInputError(f"rho must be >= 0, got {self.rho}")
        if not (np.isfinite(self.box_scale) and self.box_scale > 1.0):
            raise DgtdInputError(f"box_scale must be > 1 (the boxes must contain the saddle point), got {self.box_scale}")
        if self.boxes is not None and (len(self.boxes) != 4 or any(not b > 0 for b in self.boxes)):
            raise DgtdInputError(f"boxes must be four positive half-widths (theta, v, mu, w), got {self.boxes}")


class DGTDState(NamedTuple):
    theta: np.ndarray
    v: np.ndarray
    mu: np.ndarray
    w: np.ndarray


def init(n_seeds: int, n_agents: int, n_features: int) -> DGTDState:
    """Algorithm 1 line 3: all variables start at zero."""
    z = np.zeros((n_seeds, n_agents, n_features))
    return DGTDState(z, z.copy(), z.copy(), z.copy())


def direction(state: DGTDState, phi, phi_next, r, ratio, lap, gamma: float, kappa: float, rho: float):
    """Stochastic gradient of the Lagrangian at step k, (g_theta, g_v, g_mu, g_w), all (B, N, q).

    ``phi``, ``phi_next`` (B, N or 1, q); ``r`` (B, N); ``ratio`` (B, N or 1), the importance ratio;
    ``lap(X)`` applies L(k) along the agent axis. Its expectation over samples and graphs is the gradient
    of eq. (Lagrangian2) plus the rho terms (`dgtd.problems.exact.lagrangian_gradient`); the ratio
    multiplies the terms that come from the TD error, as in off-policy GTD.
    """
    theta, v, mu, w = state
    Lw, Lv, Lmu = lap(w), lap(v), lap(mu)
    phi_theta = np.einsum("bnq,bnq->bn", np.broadcast_to(phi, theta.shape), theta)
    phi_w = np.einsum("bnq,bnq->bn", np.broadcast_to(phi, w.shape), w)
    phin_w = np.einsum("bnq,bnq->bn", np.broadcast_to(phi_next, w.shape), w)
    # Line 7, theta: phi phi^T theta + ratio (phi phi^T w - gamma phi phi'^T w - phi r)
    g_theta = phi * (phi_theta + ratio * (phi_w - gamma * phin_w - r))[..., None]
    # Line 7, v: v - (|N_i(k)| w_i - sum_j w_j) = v - (L(k) w)_i
    g_v = v - Lw
    # Line 8, mu: descent on -(L(k) w)_i, plus rho mu
    g_mu = -Lw + rho * mu
    # Line 8, w: ascent on ratio (phi - gamma phi') phi^T theta - (L v)_i - (L mu)_i - kappa (L w)_i - rho w
    g_w = (ratio * phi_theta)[..., None] * (phi - gamma * phi_next) - Lv - Lmu - kappa * Lw - rho * w
    return g_theta, g_v, g_mu, g_w


def update(state: DGTDState, phi, phi_next, r, ratio, lap, alpha: float, gamma, kappa, rho, boxes) -> DGTDState:
    """One step of Algorithm 1: lines 7-8 (descent on theta, v, mu; ascent on w) and line 9 (projection).

    ``boxes`` = (c_theta, c_v, c_mu, c_w): the half-widths of the max-norm balls C_theta, C_v, C_mu, C_w.
    """
    g_theta, g_v, g_mu, g_w = direction(state, phi, phi_next, r, ratio, lap, gamma, kappa, rho)
    theta, v, mu, w = state
    b_theta, b_v, b_mu, b_w = boxes
    return DGTDState(
        np.clip(theta - alpha * g_theta, -b_theta, b_theta),
        np.clip(v - alpha * g_v, -b_v, b_v),
        np.clip(mu - alpha * g_mu, -b_mu, b_mu),
        np.clip(w + alpha * g_w, -b_w, b_w),
    )
