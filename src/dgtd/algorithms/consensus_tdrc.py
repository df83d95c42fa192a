"""Distributed TDRC with consensus: each agent follows TDRC's direction (`dgtd.algorithms.tdrc`, Ghiassian et al.
2020) on its own reward and mixes its neighbours' value weights with Metropolis weights, as consensus TD(0) does TD's
(`dgtd.algorithms.consensus_td0`, Doan, Maguluri and Romberg 2019):

    w_i(k+1)     = sum_j W_ij(k) w_j(k) + alpha_k ratio_i (delta_i phi_i - gamma phi'_i phi_i^T theta_i(k))
    theta_i(k+1) = theta_i(k) + beta_k ((ratio_i delta_i - phi_i^T theta_i(k)) phi_i - penalty theta_i(k))

with delta_i = r_i + gamma phi'_i^T w_i - phi_i^T w_i, W(k) the Metropolis weights of the links up at step k and one
step size (beta_k = eta alpha_k, eta 1), as TDRC.

Fixed point. With steps that decay, the w_i reach consensus on a w where the agents' mean directions cancel in the
mean mixing's weights pi (uniform where the mean mixing is doubly stochastic, as on perfect links): with theta_i at
(M + penalty I)^-1 (b_i - A w), sum_i pi_i E[g_i] = (A^T + penalty I)(M + penalty I)^-1 (sum_i pi_i b_i - A w) = 0,
so w = A^-1 sum_i pi_i b_i whenever A^T + penalty I is invertible: w* on perfect links, and under lost messages
the same point as every Metropolis method's (`dgtd.problems.exact.weighted_w_star`). Unlike gradient tracking it
needs no doubly stochastic mixing, so it survives lost, late and asleep links. Each agent sends one vector, w_i.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, NamedTuple

import numpy as np

from dgtd.algorithms.base import zeros
from dgtd.algorithms.tdc import TDC
from dgtd.algorithms.tdrc import Penalised, penalised


class ConsensusTDRCState(NamedTuple):
    theta: np.ndarray  # (B, N, q) TDRC's auxiliary vector, each agent's own
    w: np.ndarray  # (B, N, q) value weights, sent


@dataclass(frozen=True)
class ConsensusTDRC(Penalised):
    """TDRC with Metropolis consensus on w; fields as `dgtd.algorithms.tdrc.TDRC` (one step size, ``penalty``), its
    directions TDC's (`dgtd.algorithms.tdc.TDC.terms`), each agent's own."""

    name: ClassVar[str] = "consensus-tdrc"
    description: ClassVar[str] = "distributed TDRC with Metropolis consensus (TDRC's direction, Doan et al.'s mixing)"
    color: ClassVar[str] = "#7f7f7f"
    reads: ClassVar = TDC.reads
    coefficients = staticmethod(TDC.coefficients)
    terms = staticmethod(TDC.terms)
    messages: ClassVar[tuple[str, ...]] = ("w",)
    mixing: ClassVar[str] = "metropolis"  # W(k) x = x - inbox.metropolis(x)

    def init(self, seeds: int, agents: int, features: int) -> ConsensusTDRCState:
        return ConsensusTDRCState(*zeros(seeds, agents, features, 2))

    @staticmethod
    def transmit(x):
        theta, w = x
        return (w,)

    @staticmethod
    def feature(p, x, heard, d, steps):
        """W(k) w + alpha_k d_w, with W(k) w = w - L_W(k) w; theta's own penalised step."""
        theta, w = x
        (Lw,) = heard
        d_w, d_theta = d
        alpha, beta = steps
        return penalised(theta, d_theta, beta, p.penalty), w - Lw + alpha * d_w
