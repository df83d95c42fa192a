"""GTD2 (Sutton, Maei, Precup, Bhatnagar, Silver, Szepesvari, Wiewiora, ICML 2009), as pure functions.

In the paper's notation the value weights are theta and the auxiliary vector is w; dgtd's glossary (the
one of the DGTD paper, where theta plays the auxiliary's role) swaps them: here ``w`` are the value weights
and ``theta`` the auxiliary vector, which tracks M^-1 (b - A w) exactly as DGTD's theta does. With the
importance ratio (off-policy GTD2, Maei 2011), at each sample:

    w     <- w     + alpha_k ratio (phi - gamma phi') (phi^T theta)           (the paper's theta update)
    theta <- theta + eta alpha_k (ratio delta - phi^T theta) phi              (the paper's w update)

with delta = r + gamma phi'^T w - phi^T w and the paper's two step sizes alpha, beta = eta alpha. The mean
path is w' = A^T theta, theta' = eta (b - A w - M theta). The centralised learner averages these terms over
the N transitions the agents observed (see `dgtd.algorithms.td0`); `local` applies them per agent. In the paper's
notation beta_k (`TwoTimescale.aux_step`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar, NamedTuple

import numpy as np

from dgtd.algorithms.base import StepSizes, check_nonnegative, td_error, zeros
from dgtd.errors import DgtdInputError
from dgtd.fields import option


class TwoTimescaleParams(NamedTuple):
    eta: float  # beta_k = eta alpha0 (alpha_k / alpha0)^timescale (`TwoTimescale`)
    alpha0: float
    timescale: float


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

    eta: float = field(
        default=1.0, metadata=option("Auxiliary step ratio: beta_k = eta alpha0 (alpha_k / alpha0)^timescale.")
    )
    timescale: float = field(
        default=1.0,
        metadata=option("Exponent p in (0, 1] of the auxiliary step beta_k = eta alpha0 (alpha_k / alpha0)^p."),
    )

    Params: ClassVar[Any] = TwoTimescaleParams

    def __post_init__(self):
        super().__post_init__()
        check_nonnegative("eta (auxiliary step size / main step size)", self.eta, strict=True)
        if not (np.isfinite(self.timescale) and 0.0 < self.timescale <= 1.0):
            raise DgtdInputError(f"timescale must lie in (0, 1] (1: a constant ratio eta), got {self.timescale}")

    def aux_step(self, alpha: float) -> float:
        """beta_k = eta alpha0 (alpha_k / alpha0)^timescale; eta alpha_k exactly for timescale 1."""
        return aux_step(alpha, self.eta, self.alpha0, self.timescale)

    @staticmethod
    def steps(p, alpha):
        """alpha_k and the auxiliary step beta_k."""
        return alpha, aux_step(alpha, p.eta, p.alpha0, p.timescale)


def aux_step(alpha, eta, alpha0, timescale):
    """The auxiliary step beta_k of `TwoTimescale`."""
    return eta * alpha if timescale == 1.0 else eta * alpha0 * (alpha / alpha0) ** timescale


@dataclass(frozen=True)
class GTD2(TwoTimescale):
    """Centralised GTD2 on the average reward; fields as `TwoTimescale`. Its one learner averages the directions of
    the N transitions the agents observed (see `dgtd.algorithms.td0`), all at the values of step k."""

    name: ClassVar[str] = "gtd2"
    description: ClassVar[str] = "centralised GTD2 on the average reward (Sutton et al. 2009)"
    color: ClassVar[str] = "#1f77b4"
    centralised: ClassVar[bool] = True
    reads: ClassVar = (("phi", "w"), ("phi_next", "w"), ("phi", "theta"))

    def init(self, seeds: int, agents: int, features: int) -> GTDState:
        return GTDState(*zeros(seeds, 1, features, 2))

    @staticmethod
    def coefficients(p, dots, r, ratio, gamma):
        """ratio phi^T theta (of the value direction), and ratio delta - phi^T theta (of the auxiliary's)."""
        phi_w, phin_w, phi_theta = dots
        return ratio * phi_theta, ratio * td_error(phin_w, phi_w, r, gamma) - phi_theta

    @staticmethod
    def terms(p, phi, phi_next, c, gamma):
        """GTD2's value direction ratio (phi - gamma phi') phi^T theta, and the auxiliary's (ratio delta - phi^T
        theta) phi."""
        c_w, c_theta = c
        return c_w * (phi - gamma * phi_next), c_theta * phi

    @staticmethod
    def feature(p, x, heard, d, steps):
        """w += alpha_k d_w; theta += beta_k d_theta."""
        w, theta = x
        d_w, d_theta = d
        alpha, beta = steps
        return w + alpha * d_w, theta + beta * d_theta
