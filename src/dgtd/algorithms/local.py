"""`local`: every agent runs GTD2 (`dgtd.algorithms.gtd2`) on its own reward and never communicates.

Agent i converges to the GTD2 fixed point of its own reward, w_i = A^-1 b_i, not to w* = A^-1 b_mean: the
gap is what the network buys. The state is GTD2's with an agent axis, (B, N, q).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from dgtd.algorithms.base import zeros
from dgtd.algorithms.gtd2 import GTDConfig, GTDState, theta_terms, w_terms
from dgtd.samples import Sample


@dataclass(frozen=True)
class Local(GTDConfig):
    """N independent GTD2 learners; fields as `dgtd.algorithms.gtd2.GTDConfig`, one estimate per agent."""

    name: ClassVar[str] = "local"
    description: ClassVar[str] = "each agent runs GTD2 on its own reward, no communication"
    color: ClassVar[str] = "#ff7f0e"

    def init(self, seeds: int, agents: int, features: int) -> GTDState:
        return GTDState(*zeros(seeds, agents, features, 2))

    def update(self, state: GTDState, sample: Sample, inbox, alpha: float) -> GTDState:
        """One GTD2 step of every agent on its own sample and reward."""
        shape = state.w.shape
        dw = np.broadcast_to(w_terms(state, sample), shape)
        return GTDState(state.w + alpha * dw, state.theta + self.aux_step(alpha) * theta_terms(state, sample))
