"""Distributed TD(0) with consensus (Doan, Maguluri, Romberg, ICML 2019), as pure functions.

Each agent mixes its neighbours' weights and takes a TD(0) step on its own reward (their Algorithm 1):

    w_i(k+1) = sum_j W_ij(k) w_j(k) + alpha_k ratio_i delta_i(k) phi_i(k),
    delta_i(k) = r_i + gamma phi'_i^T w_i(k) - phi_i^T w_i(k),

with Metropolis weights on the graph up at step k: W_ij = 1 / (1 + max(d_i(k), d_j(k))) on the edges up,
W_ii = 1 - sum_j W_ij, where d_i(k) is agent i's number of links up. W(k) is symmetric and doubly
stochastic for every graph, so sum_j W_ij w_j = w_i - (L_W(k) w)_i with L_W(k) the Laplacian weighted by
the Metropolis weights (`dgtd.channels.Inbox.metropolis`). The paper's analysis uses a fixed W; here W(k) follows
the random network. No projection: off-policy the method may diverge (the importance ratio multiplies the TD step
only), and the run reports that. Each agent sends one vector, w_i, to each neighbour per step.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, NamedTuple

import numpy as np

from dgtd.algorithms.base import StepSizes, zeros
from dgtd.algorithms.td0 import TD0


class ConsensusState(NamedTuple):
    w: np.ndarray  # (B, N, q)


@dataclass(frozen=True)
class ConsensusTD0(StepSizes):
    """Consensus TD(0) with Metropolis weights; ``alpha0``, ``beta``, ``schedule`` give alpha_k; the TD direction is
    TD(0)'s (`dgtd.algorithms.td0.TD0.terms`), each agent's own."""

    name: ClassVar[str] = "consensus-td0"
    description: ClassVar[str] = "distributed TD(0) with Metropolis consensus (Doan, Maguluri, Romberg 2019)"
    color: ClassVar[str] = "#2ca02c"
    reads: ClassVar = TD0.reads
    coefficients = staticmethod(TD0.coefficients)
    terms = staticmethod(TD0.terms)
    messages: ClassVar[tuple[str, ...]] = ("w",)
    mixing: ClassVar[str] = "metropolis"  # W(k) x = x - inbox.metropolis(x)

    def init(self, seeds: int, agents: int, features: int) -> ConsensusState:
        return ConsensusState(*zeros(seeds, agents, features, 1))

    @staticmethod
    def transmit(x):
        return x

    @staticmethod
    def feature(p, x, heard, d, steps):
        """W(k) w + alpha_k ratio delta phi, with W(k) w = w - L_W(k) w (`dgtd.channels.Inbox.metropolis`)."""
        (w,) = x
        (Lw,) = heard
        (d_w,) = d
        (alpha,) = steps
        return (w - Lw + alpha * d_w,)
