"""GTD2 (Sutton, Maei, Precup, Bhatnagar, Silver, Szepesvari, Wiewiora, ICML 2009), as pure functions.

In the paper's notation the value weights are theta and the auxiliary vector is w; dgtd's glossary (the
one of the DGTD paper, where theta plays the auxiliary's role) swaps them: here ``w`` are the value weights
and ``theta`` the auxiliary vector, which tracks M^-1 (b - A w) exactly as DGTD's theta does. With the
importance ratio (off-policy GTD2, Maei 2011), at each sample:

    w     <- w     + alpha_k ratio (phi - gamma phi') (phi^T theta)           (the paper's theta update)
    theta <- theta + eta alpha_k (ratio delta - phi^T theta) phi              (the paper's w update)

with delta = r + gamma phi'^T w - phi^T w and the paper's two step sizes alpha, beta = eta alpha. The mean
path is w' = A^T theta, theta' = eta (b - A w - M theta). The centralised learner averages these terms over
the N transitions the agents observed (see `dgtd.algorithms.td0`); `local` applies them per agent.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, NamedTuple

import numpy as np

from dgtd.algorithms.base import StepSizes, agent_mean, check_nonnegative, discount, dot, td_error, zeros
from dgtd.errors import DgtdInputError
from dgtd.samples import Sample


class GTDState(NamedTuple):
    w: np.ndarray  # (B, 1, q) centralised, (B, N, q) local
    theta: np.ndarray


@dataclass(frozen=True)
class TwoTimescale(StepSizes):
    """Fields shared by the two-timescale gradient-TD learners (GTD2, TDC, local GTD2, TDC with tracking).

    - ``alpha0``, ``beta``, ``schedule``: the value step sizes alpha_k (see `dgtd.algorithms.stepsizes`).
    - ``eta``, ``timescale`` p in (0, 1]: the auxiliary step size is beta_k = eta alpha0 (alpha_k / alpha0)^p
      (Sutton et al. 2009's beta). p = 1 keeps a constant ratio beta_k = eta alpha_k (one timescale, which the
      saddle-point view of GTD2 covers: Liu et al. 2015); p < 1 makes beta_k decay more slowly than alpha_k, so
      that alpha_k / beta_k -> 0 as the two-timescale convergence proofs of GTD2 and TDC require (Sutton et al.
      2009, section 5).
    """

    eta: float = 1.0
    timescale: float = 1.0

    def __post_init__(self):
        super().__post_init__()
        check_nonnegative("eta (auxiliary step size / main step size)", self.eta, strict=True)
        if not (np.isfinite(self.timescale) and 0.0 < self.timescale <= 1.0):
            raise DgtdInputError(f"timescale must lie in (0, 1] (1: a constant ratio eta), got {self.timescale}")

    def aux_step(self, alpha: float) -> float:
        """beta_k = eta alpha0 (alpha_k / alpha0)^timescale; eta alpha_k exactly for timescale 1."""
        return aux_step(alpha, self.eta, self.alpha0, self.timescale)


@dataclass(frozen=True)
class GTDConfig(TwoTimescale):
    """A centralised two-timescale learner (GTD2, TDC): the value step of ``value_terms`` and theta's step, averaged
    over the N observed transitions."""

    @staticmethod
    def value_terms(state: GTDState, sample: Sample) -> np.ndarray:
        """The value step's terms of each observed transition: each learner's own."""
        raise NotImplementedError

    def init(self, seeds: int, agents: int, features: int) -> GTDState:
        return GTDState(*zeros(seeds, 1, features, 2))

    def update(self, state: GTDState, sample: Sample, inbox, alpha: float) -> GTDState:
        """One step of the centralised learner: its value terms (``value_terms``) and the auxiliary terms, both
        averaged over the N observed transitions and both at the values of step k."""
        N = sample.r.shape[1]
        dw, dtheta = agent_mean(self.value_terms(state, sample), N), agent_mean(theta_terms(state, sample), N)
        return GTDState(state.w + alpha * dw, state.theta + self.aux_step(alpha) * dtheta)


def aux_step(alpha: float, eta: float, alpha0: float, timescale: float) -> float:
    """The auxiliary step beta_k of `GTDConfig` (the compiled kernels compute the same expression)."""
    return eta * alpha if timescale == 1.0 else eta * alpha0 * (alpha / alpha0) ** timescale


def theta_terms(state: GTDState, sample: Sample) -> np.ndarray:
    """Per-agent auxiliary terms (ratio_i delta_i - phi_i^T theta) phi_i, shape (B, N, q)."""
    delta = td_error(sample, state.w)
    return (np.broadcast_to(sample.ratio, delta.shape) * delta - dot(sample.phi, state.theta))[..., None] * sample.phi


def w_terms(state: GTDState, sample: Sample) -> np.ndarray:
    """Per-agent GTD2 value terms ratio_i (phi_i - gamma phi'_i) (phi_i^T theta), shape (B, N or 1, q)."""
    phi, phi_next, _, ratio, _ = sample
    return (ratio * dot(phi, state.theta))[..., None] * (phi - discount(sample) * phi_next)


@dataclass(frozen=True)
class GTD2(GTDConfig):
    """Centralised GTD2 on the average reward; fields as `GTDConfig`."""

    name: ClassVar[str] = "gtd2"
    description: ClassVar[str] = "centralised GTD2 on the average reward (Sutton et al. 2009)"
    color: ClassVar[str] = "#1f77b4"

    @staticmethod
    def value_terms(state: GTDState, sample: Sample) -> np.ndarray:
        return w_terms(state, sample)
