"""Laplacian primal-dual distributed TD (Lim and Lee, "A primal-dual perspective for distributed
TD-learning", IJCAI 2025), as pure functions, written from its update equations:

    w_i  <- w_i  + alpha_k (ratio_i delta_i phi_i - eta (L(k) w)_i - eta (L(k) mu)_i)
    mu_i <- mu_i + alpha_k eta (L(k) w)_i

with delta_i = r_i + gamma phi'_i^T w_i - phi_i^T w_i and L(k) the Laplacian of the graph up at step k.
Lim and Lee write theta for the value weights and w for the multiplier; in dgtd's glossary the value
weights are ``w`` and the multiplier of the consensus constraint L w = 0 is ``mu``. Mean path on a graph
with mean Laplacian L: w' = b_i - A w_i - eta L w - eta L mu, mu' = eta L w; at a rest point L w = 0
(consensus) and summing over agents gives b_mean - A w = 0. The importance ratio multiplies the TD term
only, so off-policy the method inherits TD(0)'s divergence. Each agent sends w_i and mu_i (two vectors)
to each neighbour per step.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar, NamedTuple

import numpy as np

from dgtd.algorithms.base import StepSizes, check_nonnegative, zeros
from dgtd.algorithms.td0 import TD0
from dgtd.fields import option


class PDTDState(NamedTuple):
    w: np.ndarray  # (B, N, q)
    mu: np.ndarray  # (B, N, q)


class PDTDParams(NamedTuple):
    eta: float


@dataclass(frozen=True)
class PDTD(StepSizes):
    """Primal-dual distributed TD. ``alpha0``, ``beta``, ``schedule``: alpha_k; ``eta`` >= 0 the consensus weight. The
    TD direction is TD(0)'s (`dgtd.algorithms.td0.TD0.terms`), each agent's own."""

    eta: float = field(default=1.0, metadata=option("Weight of the consensus terms."))

    name: ClassVar[str] = "pd-td"
    description: ClassVar[str] = "Laplacian primal-dual distributed TD (Lim and Lee 2025)"
    color: ClassVar[str] = "#9467bd"
    reads: ClassVar = TD0.reads
    coefficients = staticmethod(TD0.coefficients)
    terms = staticmethod(TD0.terms)
    messages: ClassVar[tuple[str, ...]] = ("w", "mu")
    Params: ClassVar = PDTDParams

    def __post_init__(self):
        super().__post_init__()
        check_nonnegative("eta", self.eta)

    def init(self, seeds: int, agents: int, features: int) -> PDTDState:
        return PDTDState(*zeros(seeds, agents, features, 2))

    @staticmethod
    def transmit(x):
        return x

    @staticmethod
    def feature(p, x, heard, d, steps):
        """w_i += alpha_k (ratio delta_i phi_i - eta (L(k) w)_i - eta (L(k) mu)_i); mu_i += alpha_k eta (L(k) w)_i;
        both from the values at step k."""
        w, mu = x
        Lw, Lmu = heard
        (d_w,) = d
        (alpha,) = steps
        return w + alpha * (d_w - p.eta * Lw - p.eta * Lmu), mu + alpha * p.eta * Lw
