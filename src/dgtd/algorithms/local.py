"""`local`: every agent runs GTD2 (`dgtd.algorithms.gtd2`) on its own reward and never communicates.

Agent i converges to the GTD2 fixed point of its own reward, w_i = A^-1 b_i, not to w* = A^-1 b_mean: the
gap is what the network buys. The state is GTD2's with an agent axis, (B, N, q).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dgtd.algorithms import gtd2
from dgtd.algorithms.gtd2 import GTDConfig, GTDState


@dataclass(frozen=True)
class Local(GTDConfig):
    """N independent GTD2 learners; fields as `dgtd.algorithms.gtd2.GTDConfig`, one estimate per agent."""

    name = "local"

    def init(self, n_seeds: int, n_agents: int, n_features: int) -> GTDState:
        z = np.zeros((n_seeds, n_agents, n_features))
        return GTDState(z, z.copy())


def update(state: GTDState, phi, phi_next, r, ratio, alpha: float, eta: float, gamma: float) -> GTDState:
    """One GTD2 step of every agent on its own sample and reward."""
    return gtd2.update(state, phi, phi_next, r, ratio, alpha, eta, gamma, central=False)
