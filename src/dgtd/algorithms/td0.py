"""Centralised linear TD(0) (Sutton 1988; the TD(0) baseline of Sutton et al. 2009), as pure functions.

Glossary (the same in every algorithm of dgtd): ``w`` are the value-function weights, V(s) ~ phi(s)^T w
(Sutton et al. write theta); the step's data is a `dgtd.samples.Sample`.

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
from typing import ClassVar, NamedTuple

import numpy as np

from dgtd.algorithms.base import StepSizes, agent_mean, ratio_td_step, zeros
from dgtd.samples import Sample


class TD0State(NamedTuple):
    w: np.ndarray  # (B, 1, q)


@dataclass(frozen=True)
class TD0(StepSizes):
    """Centralised TD(0): w <- w + alpha_k (1/N) sum_i ratio_i delta_i phi_i.

    No projection: off-policy TD(0) may diverge (Baird's counterexample), and the run reports that.
    """

    name: ClassVar[str] = "td0"
    description: ClassVar[str] = "centralised TD(0) on the average reward"
    color: ClassVar[str] = "#7f7f7f"

    def init(self, seeds: int, agents: int, features: int) -> TD0State:
        return TD0State(*zeros(seeds, 1, features, 1))

    def update(self, state: TD0State, sample: Sample, inbox, alpha: float) -> TD0State:
        """w_{k+1} = w_k + alpha_k ratio delta_k phi_k, averaged over the N observed transitions; its mean over
        samples is b_mean - A w."""
        return TD0State(state.w + alpha * agent_mean(ratio_td_step(sample, state.w), sample.r.shape[1]))
