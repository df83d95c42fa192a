"""`local`: every agent runs GTD2 (`dgtd.algorithms.gtd2`) on its own reward and never communicates.

Agent i converges to the GTD2 fixed point of its own reward, w_i = A^-1 b_i, not to w* = A^-1 b_mean: the
gap is what the network buys. The state is GTD2's with an agent axis, (B, N, q).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from dgtd.algorithms.base import zeros
from dgtd.algorithms.gtd2 import GTD2, GTDState


@dataclass(frozen=True)
class Local(GTD2):
    """N independent GTD2 learners, GTD2's arithmetic on each agent's own sample; fields as
    `dgtd.algorithms.gtd2.TwoTimescale`, one estimate per agent."""

    name: ClassVar[str] = "local"
    description: ClassVar[str] = "each agent runs GTD2 on its own reward, no communication"
    color: ClassVar[str] = "#ff7f0e"
    centralised: ClassVar[bool] = False

    def init(self, seeds: int, agents: int, features: int) -> GTDState:
        return GTDState(*zeros(seeds, agents, features, 2))
