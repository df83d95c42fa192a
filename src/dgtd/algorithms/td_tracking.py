"""Decentralised TD(0) with gradient tracking (Wang, Lu, Giannakis, Tesauro, Sun, "Decentralized TD tracking with
linear function approximation and its finite-time analysis", NeurIPS 2020).

Each agent keeps a tracker z_i of the network-average TD direction, mixes its neighbours' weights and trackers
with the Metropolis weights W(k) of the links up at step k (as `dgtd.algorithms.consensus_td0`), and moves along
its tracker:

    g_i(k)     = ratio_i delta_i(k) phi_i(k),  delta_i(k) = r_i + gamma phi'_i^T w_i(k) - phi_i^T w_i(k)
    z_i(k)     = sum_j W_ij(k) z_j(k-1) + g_i(k) - g_i(k-1)          (z(-1) = g(-1) = 0, so z(0) = g(0))
    w_i(k+1)   = sum_j W_ij(k) w_j(k) + alpha_k z_i(k)

W(k) is doubly stochastic, so sum_i z_i(k) = sum_i g_i(k) at every step: z_i tracks the average direction
(1/N) sum_i g_i, whose mean is b_mean - A w, and the fixed point is consensus on w* = A^-1 b_mean (on-policy).
Both mixes use the step's links; each agent sends w_i and z_i (two vectors) to each neighbour per step. No
projection: off-policy it inherits TD(0)'s divergence.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, NamedTuple

import numpy as np

from dgtd.algorithms.base import StepSizes, zeros
from dgtd.algorithms.td0 import TD0


class TrackingState(NamedTuple):
    g: np.ndarray  # (B, N, q) the last local TD direction g_i(k), its own
    w: np.ndarray  # (B, N, q) value weights w_i(k + 1), sent
    z: np.ndarray  # (B, N, q) tracker z_i(k), sent


@dataclass(frozen=True)
class TDTracking(StepSizes):
    """TD(0) with gradient tracking; ``alpha0``, ``beta``, ``schedule`` give alpha_k; the local direction is TD(0)'s
    (`dgtd.algorithms.td0.TD0.terms`)."""

    name: ClassVar[str] = "td-tracking"
    description: ClassVar[str] = "distributed TD(0) with gradient tracking (Wang et al. 2020)"
    color: ClassVar[str] = "#8c564b"
    reads: ClassVar = TD0.reads
    coefficients = staticmethod(TD0.coefficients)
    terms = staticmethod(TD0.terms)
    messages: ClassVar[tuple[str, ...]] = ("w", "z")
    mixing: ClassVar[str] = "metropolis"  # W(k) x = x - inbox.metropolis(x)

    def init(self, seeds: int, agents: int, features: int) -> TrackingState:
        return TrackingState(*zeros(seeds, agents, features, 3))

    @staticmethod
    def transmit(x):
        g, w, z = x
        return w, z

    @staticmethod
    def feature(p, x, heard, d, steps):
        """One step: the tracker first (it needs this step's direction), then w along it (`track`)."""
        g, w, z = x
        (g_new,) = d
        (alpha,) = steps
        w_new, z_new = track(w, z, g, g_new, heard, alpha)
        return g_new, w_new, z_new


def track(w, z, g_prev, g, heard, alpha):
    """(w(k+1), z(k)) of gradient tracking (Wang et al. 2020) given this step's local direction g and the last g_prev:
    z(k) = W(k) z(k-1) + g(k) - g(k-1), w(k+1) = W(k) w(k) + alpha_k z(k), with W(k) x = x - (L_W(k) x) and
    ``heard`` = ((L_W(k) w)_i, (L_W(k) z)_i)."""
    Lw, Lz = heard
    z_new = z - Lz + g - g_prev
    return w - Lw + alpha * z_new, z_new
