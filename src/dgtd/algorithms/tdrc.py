"""TDRC, TD with regularised corrections (Ghiassian, Patterson, Garg, Gupta, White and White, "Gradient temporal-
difference learning with regularized corrections", ICML 2020), as pure functions.

TDC (`dgtd.algorithms.tdc`) with an l2 penalty ``penalty`` (the paper's beta; 1 by default, as in its experiments)
on the auxiliary vector and one step size for both (eta = 1, timescale 1: its "one stepsize"). Glossary as in
`dgtd.algorithms.gtd2`: ``w`` the value weights (the paper's w), ``theta`` the auxiliary vector (the paper's h). At
each sample, with delta = r + gamma phi'^T w - phi^T w and the importance ratio (the paper's Algorithm 1, rho):

    w     <- w     + alpha_k ratio (delta phi - gamma phi' (phi^T theta))                   (the paper's w update)
    theta <- theta + beta_k ((ratio delta - phi^T theta) phi - penalty theta)               (the paper's h update)

with beta_k = eta alpha_k. Mean path: w' = b - A w - (M - A^T) theta, theta' = b - A w - (M + penalty I) theta. At
theta's limit (M + penalty I)^-1 (b - A w) the value step is (A^T + penalty I)(M + penalty I)^-1 (b - A w), which
vanishes only where A w = b whenever A^T + penalty I is invertible: TD's fixed point w* = A^-1 b, reached on-policy at
about TD's pace (the penalty keeps theta small where TD alone would do), and convergent on Baird's counterexample
(the paper's Theorem 3.1 for penalty below the smallest eigenvalue of a matrix of A and M; on-policy, any penalty).
The centralised learner averages the terms over the N transitions the agents observed (see `dgtd.algorithms.td0`);
the penalty, a function of theta alone, is applied once a step.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar, NamedTuple

from dgtd.algorithms.base import check_nonnegative
from dgtd.algorithms.gtd2 import TwoTimescale
from dgtd.algorithms.tdc import TDC
from dgtd.fields import option


class TDRCParams(NamedTuple):
    eta: float
    alpha0: float
    timescale: float
    penalty: float  # the paper's beta


@dataclass(frozen=True)
class Penalised(TwoTimescale):
    """The step sizes of TDRC and of the methods built on its direction: one step size (eta 1, timescale 1), as the
    paper runs it, and ``penalty``, its l2 penalty on theta."""

    timescale: float = 1.0
    penalty: float = field(
        default=1.0,
        metadata=option("L2 penalty on the auxiliary vector theta (Ghiassian et al. 2020's beta; 0 is TDC)."),
    )

    Params: ClassVar = TDRCParams

    def __post_init__(self):
        super().__post_init__()
        check_nonnegative("penalty (TDRC's l2 penalty on theta)", self.penalty)


def penalised(theta, d_theta, beta, penalty):
    """theta's TDRC step: theta + beta_k (d_theta - penalty theta)."""
    return theta + beta * (d_theta - penalty * theta)


@dataclass(frozen=True)
class TDRC(Penalised, TDC):
    """Centralised TDRC on the average reward: TDC (`dgtd.algorithms.tdc.TDC`) whose auxiliary step carries the l2
    penalty ``penalty`` on theta (`Penalised`)."""

    name: ClassVar[str] = "tdrc"
    description: ClassVar[str] = "centralised TDRC, TDC with regularised corrections (Ghiassian et al. 2020)"
    color: ClassVar[str] = "#bcbd22"

    @staticmethod
    def feature(p, x, heard, d, steps):
        """w += alpha_k d_w; theta += beta_k (d_theta - penalty theta)."""
        w, theta = x
        d_w, d_theta = d
        alpha, beta = steps
        return w + alpha * d_w, penalised(theta, d_theta, beta, p.penalty)
