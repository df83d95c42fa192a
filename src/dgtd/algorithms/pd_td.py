"""Laplacian primal-dual distributed TD (Lim and Lee, "A primal-dual perspective for distributed
TD-learning", IJCAI 2025), as pure functions, written from its update equations:

    w_i  <- w_i  + alpha_k (ratio_i delta_i phi_i - eta (L(k) w)_i - eta (L(k) mu)_i)
    mu_i <- mu_i + alpha_k eta (L(k) w)_i

with delta_i = r_i + gamma phi'_i^T w_i - phi_i^T w_i and L(k) the Laplacian of the graph up at step k.
Lim and Lee write theta for the value weights and w for the multiplier; in dgtd's glossary the value
weights are ``w`` and the multiplier of the consensus constraint L w = 0 is ``mu``. Mean path on a graph
with mean Laplacian L: w' = b_i - A w_i - eta L w - eta L mu, mu' = eta L w; at a rest point L w = 0
(consensus) and summing over agents gives b_mean - A w = 0. The importance ratio multiplies the TD term
only, so off-policy the method inherits TD(0)'s divergence. Each agent sends w_i and mu_i (two vectors)
to each neighbour per step.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from dgtd.algorithms.stepsizes import check_schedule
from dgtd.algorithms.td0 import td_error
from dgtd.errors import DgtdInputError


@dataclass(frozen=True)
class PDTD:
    """Primal-dual distributed TD. ``alpha0``, ``beta``, ``schedule``: alpha_k; ``eta`` >= 0 the consensus weight."""

    alpha0: float = 0.1
    beta: float = 1.0
    schedule: str = "sqrt"
    eta: float = 1.0

    name = "pd-td"
    vectors_per_direction = 2  # w_i and mu_i

    def __post_init__(self):
        check_schedule(self.schedule, self.alpha0, self.beta)
        if not (np.isfinite(self.eta) and self.eta >= 0):
            raise DgtdInputError(f"eta must be >= 0, got {self.eta}")

    def init(self, n_seeds: int, n_agents: int, n_features: int) -> "PDTDState":
        z = np.zeros((n_seeds, n_agents, n_features))
        return PDTDState(z, z.copy())

    @staticmethod
    def estimate(state: "PDTDState") -> np.ndarray:
        return state.w


class PDTDState(NamedTuple):
    w: np.ndarray  # (B, N, q)
    mu: np.ndarray  # (B, N, q)


def update(state: PDTDState, phi, phi_next, r, ratio, lap, alpha: float, gamma: float, eta: float) -> PDTDState:
    """One step; ``lap(X)`` applies L(k) along the agent axis; both updates use the values at step k."""
    w, mu = state
    Lw = lap(w)
    delta = td_error(w, phi, phi_next, r, gamma)
    td = (np.broadcast_to(ratio, delta.shape) * delta)[..., None] * phi
    return PDTDState(w + alpha * (td - eta * Lw - eta * lap(mu)), mu + alpha * eta * Lw)
