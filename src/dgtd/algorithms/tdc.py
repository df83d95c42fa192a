"""TDC, TD with gradient correction (Sutton et al., ICML 2009), as pure functions.

Glossary as in `dgtd.algorithms.gtd2`: ``w`` value weights (the paper's theta), ``theta`` the auxiliary
vector (the paper's w). With the importance ratio (off-policy TDC, Maei 2011), at each sample:

    w     <- w     + alpha_k ratio (delta phi - gamma phi' (phi^T theta))      (the paper's theta update)
    theta <- theta + eta alpha_k (ratio delta - phi^T theta) phi                (as in GTD2)

Mean path: w' = b - A w - (M - A^T) theta, since E[ratio gamma phi' phi^T] = M - A^T; at the fast-timescale
theta = M^-1 (b - A w) it is A^T M^-1 (b - A w), the negative gradient of the MSPBE.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from dgtd.algorithms.base import td_error
from dgtd.algorithms.gtd2 import GTD2


@dataclass(frozen=True)
class TDC(GTD2):
    """Centralised TDC on the average reward; fields as `dgtd.algorithms.gtd2.TwoTimescale`, the auxiliary step and
    the update of theta as GTD2's.

    Two timescales by default, as in TDC's convergence proof (Sutton et al. 2009, section 5: alpha_k / beta_k -> 0,
    theta on the faster timescale): timescale 2/3, so beta_k = eta alpha0 (alpha_k / alpha0)^(2/3). With harmonic
    value steps alpha_k ~ 1/k that is beta_k ~ k^(-2/3), which meets every condition of the proof (both sums
    infinite, both sums of squares finite, alpha_k / beta_k ~ k^(-1/3) -> 0); with the paper's alpha_k ~ 1/sqrt(k),
    beta_k ~ k^(-1/3) and the ratio still goes to 0, like k^(-1/6).
    """

    timescale: float = 2.0 / 3.0

    name: ClassVar[str] = "tdc"
    description: ClassVar[str] = "centralised TDC on the average reward (Sutton et al. 2009)"
    color: ClassVar[str] = "#17becf"

    @staticmethod
    def coefficients(p, dots, r, ratio, gamma):
        """ratio delta and ratio phi^T theta (of the value direction), and ratio delta - phi^T theta (the
        auxiliary's)."""
        phi_w, phin_w, phi_theta = dots
        ratio_delta = ratio * td_error(phin_w, phi_w, r, gamma)
        return ratio_delta, ratio * phi_theta, ratio_delta - phi_theta

    @staticmethod
    def terms(p, phi, phi_next, c, gamma):
        """TDC's value direction ratio (delta phi - gamma phi' phi^T theta), and the auxiliary's (ratio delta - phi^T
        theta) phi."""
        ratio_delta, ratio_phi_theta, c_theta = c
        return ratio_delta * phi - gamma * ratio_phi_theta * phi_next, c_theta * phi
