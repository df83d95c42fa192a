"""What every algorithm has: the fixed shape, the step-size fields, and the TD helpers they share.

An algorithm is a frozen dataclass of hyperparameters (as optax's ``GradientTransformation`` closes over them):

- ``init(seeds, agents, features) -> State``: a NamedTuple of (B, N, q) arrays, (B, 1, q) for a single learner;
- ``update(state, sample, links, alpha) -> State``: one step, pure, from a `dgtd.samples.Sample` and the step's
  `dgtd.graphs.links.Links`, with step size alpha_k;
- ``estimate(state) -> w``: the value-function weights the agents report, V(s) ~ phi(s)^T w.

Class attributes (not fields, so not settings): ``name`` (its name everywhere: configs, kernels, results),
``description``, ``color`` (its colour in every figure) and ``vectors_per_link`` (parameter vectors each agent sends
to each neighbour per step, for the message counts). Optional hooks: ``with_boxes(boxes)`` for an algorithm that
projects (the run loop hands it the resolved half-widths), ``diagnostics(state, moments, L_mean)`` for numbers
reported after a run.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Protocol

import numpy as np

from dgtd.algorithms.stepsizes import check_schedule
from dgtd.errors import DgtdInputError
from dgtd.samples import Sample


class Algorithm(Protocol):
    name: ClassVar[str]
    description: ClassVar[str]
    color: ClassVar[str]
    vectors_per_link: ClassVar[int]
    alpha0: float
    beta: float
    schedule: str

    def init(self, seeds: int, agents: int, features: int): ...

    def update(self, state, sample: Sample, links, alpha: float): ...

    def estimate(self, state) -> np.ndarray: ...


@dataclass(frozen=True)
class StepSizes:
    """The step sizes alpha_k (`dgtd.algorithms.stepsizes`): ``alpha0``, ``beta`` and the ``schedule``."""

    alpha0: float = 0.1
    beta: float = 1.0
    schedule: str = "sqrt"

    def __post_init__(self):
        check_schedule(self.schedule, self.alpha0, self.beta)

    def estimate(self, state) -> np.ndarray:
        """The value-function weights: ``state.w`` for every algorithm of dgtd."""
        return state.w


def zeros(seeds: int, rows: int, features: int, count: int) -> tuple[np.ndarray, ...]:
    """``count`` arrays of zeros (seeds, rows, features): the start of every algorithm here."""
    return tuple(np.zeros((seeds, rows, features)) for _ in range(count))


def check_nonnegative(name: str, x: float, strict: bool = False) -> None:
    ok = np.isfinite(x) and (x > 0 if strict else x >= 0)
    if not ok:
        raise DgtdInputError(f"{name} must be {'positive' if strict else '>= 0'}, got {x}")


def dot(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """x_n^T y_n over the last axis of (B, n, q) arrays, broadcasting n = 1 against n = N."""
    return np.einsum("bnq,bnq->bn", *np.broadcast_arrays(x, y))


def discount(sample: Sample) -> np.ndarray:
    """The step's discount gamma(s, s'), shaped to multiply (B, n, q) features: (B, n, 1), or (1,) for a float."""
    return np.asarray(sample.gamma)[..., None]


def td_error(sample: Sample, w: np.ndarray) -> np.ndarray:
    """delta_i = r_i + gamma phi'_i^T w - phi_i^T w, (B, N); ``w`` is (B, 1 or N, q)."""
    return sample.r + sample.gamma * dot(sample.phi_next, w) - dot(sample.phi, w)


def ratio_td_step(sample: Sample, w: np.ndarray) -> np.ndarray:
    """ratio_i delta_i phi_i, (B, N, q): the off-policy TD(0) direction of every agent (Sutton 1988; Maei 2011)."""
    delta = td_error(sample, w)
    return (np.broadcast_to(sample.ratio, delta.shape) * delta)[..., None] * sample.phi


def agent_mean(x: np.ndarray, n_agents: int) -> np.ndarray:
    """Mean over the agent axis of per-agent terms (B, N or 1, q), keeping it: a centralised learner's minibatch."""
    return np.broadcast_to(x, (x.shape[0], n_agents, x.shape[2])).mean(axis=1, keepdims=True)
