"""Centralised linear TD(0) (Sutton 1988; the TD(0) baseline of Sutton et al. 2009), as pure functions.

Glossary (the same in every algorithm of dgtd): ``w`` are the value-function weights, V(s) ~ phi(s)^T w
(Sutton et al. write theta); ``phi``, ``phi_next`` (B, N or 1, q) the features of each agent's s and s';
``r`` (B, N) the agents' rewards; ``ratio`` (B, N or 1) the importance ratios pi(a|s) / beta(a|s).

Which samples a centralised learner uses: at step k it receives the N transitions the agents observed,
(s_i, a_i, s'_i, r_i), and averages the N updates. On a shared trajectory the N transitions have the same
(s, a, s'), so this is one update with the average reward r = (1/N) sum_i r_i. On independent copies it is
a minibatch of N transitions, each with its agent's reward; its mean is still the update of the average
reward, E[ratio delta phi] = (1/N) sum_i (b_i - A w) = b_mean - A w. So the centralised methods consume
exactly the samples the distributed ones do (N agent-samples per step), and their single estimate has
shape (B, 1, q).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from dgtd.algorithms.stepsizes import check_schedule


def dot(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """x_n^T y_n over the last axis of (B, n, q) arrays, broadcasting n = 1 against n = N."""
    return np.einsum("bnq,bnq->bn", *np.broadcast_arrays(x, y))


def td_error(w: np.ndarray, phi, phi_next, r, gamma: float) -> np.ndarray:
    """delta_i = r_i + gamma phi'_i^T w - phi_i^T w, shape (B, N); ``w`` is (B, 1 or N, q)."""
    return r + gamma * dot(phi_next, w) - dot(phi, w)


def agent_mean(x: np.ndarray, n_agents: int) -> np.ndarray:
    """Mean over the agent axis of per-agent terms (B, N or 1, q), keeping it: the centralised minibatch."""
    return np.broadcast_to(x, (x.shape[0], n_agents, x.shape[2])).mean(axis=1, keepdims=True)


@dataclass(frozen=True)
class TD0:
    """Centralised TD(0): w <- w + alpha_k (1/N) sum_i ratio_i delta_i phi_i.

    - ``alpha0``, ``beta``, ``schedule``: step sizes alpha_k (see `dgtd.algorithms.stepsizes`).
    No projection: off-policy TD(0) may diverge (Baird's counterexample), and the run reports that.
    """

    alpha0: float = 0.1
    beta: float = 1.0
    schedule: str = "sqrt"

    name = "td0"
    vectors_per_direction = 0  # a single learner: no messages

    def __post_init__(self):
        check_schedule(self.schedule, self.alpha0, self.beta)

    def init(self, n_seeds: int, n_agents: int, n_features: int) -> "TD0State":
        return TD0State(np.zeros((n_seeds, 1, n_features)))

    @staticmethod
    def estimate(state: "TD0State") -> np.ndarray:
        return state.w


class TD0State(NamedTuple):
    w: np.ndarray  # (B, 1, q)


def increment(w, phi, phi_next, r, ratio, gamma: float) -> np.ndarray:
    """(1/N) sum_i ratio_i delta_i phi_i, shape (B, 1, q); its mean over samples is b_mean - A w."""
    delta = td_error(w, phi, phi_next, r, gamma)
    return agent_mean((np.broadcast_to(ratio, delta.shape) * delta)[..., None] * phi, r.shape[1])


def update(state: TD0State, phi, phi_next, r, ratio, alpha: float, gamma: float) -> TD0State:
    """One TD(0) step: w_{k+1} = w_k + alpha_k ratio delta_k phi_k, averaged over the N observed transitions."""
    return TD0State(state.w + alpha * increment(state.w, phi, phi_next, r, ratio, gamma))
