"""A user's own algorithms, for `dgtd run --algorithm tests/envs/algorithms.py:NAME`: one written in the one
definition of `dgtd.algorithms.base`, and broken ones."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, NamedTuple

import numpy as np

from dgtd.algorithms import TD0
from dgtd.algorithms.base import StepSizes, zeros


class RelaxedState(NamedTuple):
    w: np.ndarray


class RelaxedParams(NamedTuple):
    c: float


@dataclass(frozen=True)
class RelaxedConsensusTD0(StepSizes):
    """TD(0) on each agent's reward with a Laplacian consensus step of weight c,
    w_i <- w_i - c (L(k) w)_i + alpha_k ratio delta_i phi_i."""

    c: float = 0.2

    name: ClassVar[str] = "relaxed-consensus-td0"
    description: ClassVar[str] = "a user's consensus TD(0)"
    color: ClassVar[str] = "#000000"
    messages: ClassVar[tuple[str, ...]] = ("w",)
    reads: ClassVar = (("phi", "w"), ("phi_next", "w"))
    Params: ClassVar = RelaxedParams

    def init(self, seeds, agents, features):
        return RelaxedState(*zeros(seeds, agents, features, 1))

    @staticmethod
    def transmit(x):
        return x

    coefficients = staticmethod(TD0.coefficients)  # TD(0)'s ratio delta and direction ratio delta phi, reused
    terms = staticmethod(TD0.terms)

    @staticmethod
    def feature(p, x, heard, d, steps):
        (w,) = x
        (Lw,) = heard
        (d_w,) = d
        (alpha,) = steps
        return (w - p.c * Lw + alpha * d_w,)


@dataclass(frozen=True)
class RaisingInit(RelaxedConsensusTD0):
    """Its init fails."""

    def init(self, seeds, agents, features):
        raise ValueError("the user's init failed")


@dataclass(frozen=True)
class WrongFeature(RelaxedConsensusTD0):
    """Its feature returns two fields for a state of one."""

    @staticmethod
    def feature(p, x, heard, d, steps):
        (w,) = x
        return (w, w)


def not_an_algorithm():
    return 1
