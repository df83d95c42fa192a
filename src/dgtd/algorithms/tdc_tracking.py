"""Decentralised TDC with gradient tracking: the tracking recursion of Wang, Lu, Giannakis, Tesauro and Sun
("Decentralized TD tracking with linear function approximation and its finite-time analysis", NeurIPS 2020, their
Algorithm 1) applied to the direction of TDC, TD with gradient correction (Sutton et al., ICML 2009, with Maei's
2011 importance ratio), so that it evaluates off-policy, as TDC does and TD(0) does not.

Each agent keeps its value weights w_i, TDC's auxiliary vector theta_i (its own, of its own reward), a tracker z_i of
the network-average TDC direction and its last local direction g_i; it mixes its neighbours' w and z with the
Metropolis weights W(k) of the links up at step k (`dgtd.channels.Inbox.metropolis`) and moves along its tracker:

    g_i(k)       = ratio_i (delta_i phi_i - gamma phi'_i phi_i^T theta_i(k))      (TDC's value direction)
    z_i(k)       = sum_j W_ij(k) z_j(k-1) + g_i(k) - g_i(k-1)                      (z(-1) = g(-1) = 0)
    w_i(k+1)     = sum_j W_ij(k) w_j(k) + alpha_k z_i(k)
    theta_i(k+1) = theta_i(k) + beta_k (ratio_i delta_i - phi_i^T theta_i(k)) phi_i (TDC's auxiliary step)

with delta_i = r_i + gamma phi'_i^T w_i - phi_i^T w_i and two timescales as TDC's (`dgtd.algorithms.tdc.TDC`:
beta_k = eta alpha0 (alpha_k / alpha0)^(2/3)). W(k) is doubly stochastic, so sum_i z_i(k) = sum_i g_i(k) at every
step. Mean path at theta_i's fast-timescale limit M^-1 (b_i - A w): E[g_i] = b_i - A w - (M - A^T) M^-1 (b_i - A w),
whose average over the agents at consensus is A^T M^-1 (b_mean - A w), the negative gradient of the MSPBE of the
average reward: the fixed point is consensus on w* = A^-1 b_mean, on- and off-policy. Each agent sends w_i and z_i
(two vectors) to each neighbour per step; theta_i stays with it. Chen, Zhou and Chen ("Multi-agent off-policy TD
learning", 2021) study decentralised TDC with consensus averaging and mini-batches instead of tracking.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, NamedTuple

import numpy as np

from dgtd.algorithms.base import zeros
from dgtd.algorithms.gtd2 import TwoTimescale
from dgtd.algorithms.td_tracking import track
from dgtd.algorithms.tdc import TDC


class TDCTrackingState(NamedTuple):
    theta: np.ndarray  # (B, N, q) TDC's auxiliary vector, each agent's own
    g: np.ndarray  # (B, N, q) the last local TDC direction g_i(k), its own
    w: np.ndarray  # (B, N, q) value weights w_i(k + 1), sent
    z: np.ndarray  # (B, N, q) tracker z_i(k), sent


@dataclass(frozen=True)
class TDCTracking(TwoTimescale):
    """TDC with gradient tracking; ``alpha0``, ``beta``, ``schedule`` give alpha_k, ``eta`` and ``timescale`` the
    auxiliary step beta_k (two timescales by default, as `dgtd.algorithms.tdc.TDC`). The local directions are TDC's
    (`dgtd.algorithms.tdc.TDC.terms`)."""

    timescale: float = 2.0 / 3.0

    name: ClassVar[str] = "tdc-tracking"
    description: ClassVar[str] = "distributed off-policy TDC with gradient tracking (Wang et al. 2020's tracking)"
    color: ClassVar[str] = "#e377c2"
    messages: ClassVar[tuple[str, ...]] = ("w", "z")
    mixing: ClassVar[str] = "metropolis"  # W(k) x = x - inbox.metropolis(x)
    reads: ClassVar = TDC.reads
    coefficients = staticmethod(TDC.coefficients)
    terms = staticmethod(TDC.terms)

    def init(self, seeds: int, agents: int, features: int) -> TDCTrackingState:
        return TDCTrackingState(*zeros(seeds, agents, features, 4))

    @staticmethod
    def transmit(x):
        theta, g, w, z = x
        return w, z

    @staticmethod
    def feature(p, x, heard, d, steps):
        """One step: the tracker with this step's TDC direction, w along it (`dgtd.algorithms.td_tracking.track`), and
        theta's own TDC step beta_k (ratio delta - phi^T theta) phi."""
        theta, g, w, z = x
        g_new, d_theta = d
        alpha, beta = steps
        w_new, z_new = track(w, z, g, g_new, heard, alpha)
        return theta + beta * d_theta, g_new, w_new, z_new
