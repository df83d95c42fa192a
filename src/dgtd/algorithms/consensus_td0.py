"""Distributed TD(0) with consensus (Doan, Maguluri, Romberg, ICML 2019), as pure functions.

Each agent mixes its neighbours' weights and takes a TD(0) step on its own reward (their Algorithm 1):

    w_i(k+1) = sum_j W_ij(k) w_j(k) + alpha_k ratio_i delta_i(k) phi_i(k),
    delta_i(k) = r_i + gamma phi'_i^T w_i(k) - phi_i^T w_i(k),

with Metropolis weights on the graph up at step k: W_ij = 1 / (1 + max(d_i(k), d_j(k))) on the edges up,
W_ii = 1 - sum_j W_ij, where d_i(k) is agent i's number of links up. W(k) is symmetric and doubly
stochastic for every graph, so sum_j W_ij w_j = w_i - (L_W(k) w)_i with L_W(k) the Laplacian weighted by
the Metropolis weights. The paper's analysis uses a fixed W; here W(k) follows the random network. No
projection: off-policy the method may diverge (the importance ratio multiplies the TD step only), and the
run reports that. Each agent sends one vector (w_i) to each neighbour per step.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from dgtd.algorithms.stepsizes import check_schedule
from dgtd.algorithms.td0 import td_error


@dataclass(frozen=True)
class ConsensusTD0:
    """Consensus TD(0) with Metropolis weights; ``alpha0``, ``beta``, ``schedule`` give alpha_k."""

    alpha0: float = 0.1
    beta: float = 1.0
    schedule: str = "sqrt"

    name = "consensus-td0"
    vectors_per_direction = 1  # w_i

    def __post_init__(self):
        check_schedule(self.schedule, self.alpha0, self.beta)

    def init(self, n_seeds: int, n_agents: int, n_features: int) -> "ConsensusState":
        return ConsensusState(np.zeros((n_seeds, n_agents, n_features)))

    @staticmethod
    def estimate(state: "ConsensusState") -> np.ndarray:
        return state.w


class ConsensusState(NamedTuple):
    w: np.ndarray  # (B, N, q)


def metropolis_weights(edges: np.ndarray, up: np.ndarray, n_nodes: int) -> np.ndarray:
    """W_ij = 1 / (1 + max(d_i, d_j)) on each edge (i, j) up, else 0; ``up`` (..., E) bool -> (..., E) float."""
    up = np.asarray(up, dtype=np.float64)
    ends = np.zeros((edges.shape[0], n_nodes))
    ends[np.arange(edges.shape[0]), edges[:, 0]] = 1.0
    ends[np.arange(edges.shape[0]), edges[:, 1]] = 1.0
    deg = up @ ends  # (..., N): links up at each agent
    return up / (1.0 + np.maximum(deg[..., edges[:, 0]], deg[..., edges[:, 1]]))


def update(state: ConsensusState, phi, phi_next, r, ratio, mix, alpha: float, gamma: float) -> ConsensusState:
    """One step; ``mix(X)`` applies L_W(k) along the agent axis, so W(k) w = w - mix(w)."""
    w = state.w
    delta = td_error(w, phi, phi_next, r, gamma)
    return ConsensusState(w - mix(w) + alpha * (np.broadcast_to(ratio, delta.shape) * delta)[..., None] * phi)
