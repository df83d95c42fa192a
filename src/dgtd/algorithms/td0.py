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

from dgtd.algorithms.base import StepSizes, td_error, zeros


class TD0State(NamedTuple):
    w: np.ndarray  # (B, 1, q)


@dataclass(frozen=True)
class TD0(StepSizes):
    """Centralised TD(0): w <- w + alpha_k (1/N) sum_i ratio_i delta_i phi_i; its mean over samples is b_mean - A w.

    No projection: off-policy TD(0) may diverge (Baird's counterexample), and the run reports that.
    """

    name: ClassVar[str] = "td0"
    description: ClassVar[str] = "centralised TD(0) on the average reward"
    color: ClassVar[str] = "#7f7f7f"
    centralised: ClassVar[bool] = True
    reads: ClassVar = (("phi", "w"), ("phi_next", "w"))

    def init(self, seeds: int, agents: int, features: int) -> TD0State:
        return TD0State(*zeros(seeds, 1, features, 1))

    @staticmethod
    def coefficients(p, dots, r, ratio, gamma):
        """ratio delta, delta = r + gamma phi'^T w - phi^T w."""
        phi_w, phin_w = dots
        return (ratio * td_error(phin_w, phi_w, r, gamma),)

    @staticmethod
    def terms(p, phi, phi_next, c, gamma):
        """The off-policy TD(0) direction ratio delta phi (Sutton 1988; Maei 2011)."""
        (ratio_delta,) = c
        return (ratio_delta * phi,)

    @staticmethod
    def feature(p, x, heard, d, steps):
        """w_{k+1} = w_k + alpha_k d."""
        (w,) = x
        (d_w,) = d
        (alpha,) = steps
        return (w + alpha * d_w,)
