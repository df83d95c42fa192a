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
from typing import ClassVar, NamedTuple

import numpy as np

from dgtd.algorithms.base import StepSizes, check_nonnegative, ratio_td_step, zeros
from dgtd.samples import Sample


class PDTDState(NamedTuple):
    w: np.ndarray  # (B, N, q)
    mu: np.ndarray  # (B, N, q)


@dataclass(frozen=True)
class PDTD(StepSizes):
    """Primal-dual distributed TD. ``alpha0``, ``beta``, ``schedule``: alpha_k; ``eta`` >= 0 the consensus weight."""

    eta: float = 1.0

    name: ClassVar[str] = "pd-td"
    description: ClassVar[str] = "Laplacian primal-dual distributed TD (Lim and Lee 2025)"
    color: ClassVar[str] = "#9467bd"
    messages: ClassVar[tuple[str, ...]] = ("w", "mu")

    def __post_init__(self):
        super().__post_init__()
        check_nonnegative("eta", self.eta)

    def init(self, seeds: int, agents: int, features: int) -> PDTDState:
        return PDTDState(*zeros(seeds, agents, features, 2))

    def sends(self, state: PDTDState) -> dict:
        return {"w": state.w, "mu": state.mu}

    def update(self, state: PDTDState, sample: Sample, inbox, alpha: float) -> PDTDState:
        """One step; both updates use the values at step k."""
        w, mu = state
        Lw = inbox.laplacian("w")
        td = ratio_td_step(sample, w)
        return PDTDState(
            w + alpha * (td - self.eta * Lw - self.eta * inbox.laplacian("mu")), mu + alpha * self.eta * Lw
        )
