"""What every algorithm has: the fixed shape, the step-size fields, the hooks the run loop calls, and the TD helpers.

An algorithm is a frozen dataclass of hyperparameters (as optax's ``GradientTransformation`` closes over them):

- ``init(seeds, agents, features) -> State``: a NamedTuple of (B, N, q) arrays, (B, 1, q) for a single learner;
- ``messages``: the names of the vectors each agent sends its neighbours at every step (a class attribute; empty for
  an algorithm that does not communicate), and ``sends(state) -> {name: (B, N, q)}`` their values at step k;
- ``update(state, sample, inbox, alpha) -> State``: one step, pure, from a `dgtd.samples.Sample`, what each agent
  heard (a `dgtd.channels.Inbox`: the neighbour aggregates of the messages that arrived) and the step size alpha_k;
- ``estimate(state) -> w``: the value-function weights the agents report, V(s) ~ phi(s)^T w.

The channel between the agents (`dgtd.channels`) turns every agent's ``sends`` into every agent's inbox: an
algorithm never sees links. Class attributes (not fields, so not settings): ``name`` (its name everywhere: configs,
kernels, results), ``description``, ``color`` (its colour in every figure) and ``messages``.

Hooks, with the defaults of `StepSizes`, through which the run loop treats every algorithm alike:

- ``fixed_point(moments, mean_laplacian, w_star) -> FixedPoint``: the point its iterates converge to on a model, which
  the errors are measured against (w* for every agent by default), with what it reports of that point;
- ``prepare(moments, network, fixed) -> (algorithm, report)``: the algorithm as it runs on this problem (DGTD's
  projection boxes), and what to report of that;
- ``diagnostics(state, moments, mean_laplacian) -> dict``: numbers reported after a run (DGTD's KKT residuals);
- ``describe() -> str``: one line for the command line.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import ClassVar, Protocol

import numpy as np

from dgtd.algorithms.stepsizes import check_schedule
from dgtd.errors import DgtdInputError
from dgtd.samples import Sample


@dataclass(frozen=True)
class FixedPoint:
    """Where an algorithm's iterates go on a model: ``w`` (N or 1, q), one row per agent or one for all, which the
    errors are measured against, and ``report``, what summary.json says of it (e.g. DGTD's theta* and mu*)."""

    w: np.ndarray
    report: dict = field(default_factory=dict)


class Algorithm(Protocol):
    name: ClassVar[str]
    description: ClassVar[str]
    color: ClassVar[str]
    messages: ClassVar[tuple[str, ...]]
    alpha0: float
    beta: float
    schedule: str

    def init(self, seeds: int, agents: int, features: int): ...

    def sends(self, state) -> dict: ...

    def update(self, state, sample: Sample, inbox, alpha: float): ...

    def estimate(self, state) -> np.ndarray: ...

    def fixed_point(self, moments, mean_laplacian, w_star: np.ndarray) -> FixedPoint: ...

    def prepare(self, moments, network, fixed: FixedPoint) -> tuple: ...

    def diagnostics(self, state, moments, mean_laplacian) -> dict: ...

    def describe(self) -> str: ...


@dataclass(frozen=True)
class StepSizes:
    """The step sizes alpha_k (`dgtd.algorithms.stepsizes`): ``alpha0``, ``beta`` and the ``schedule``; and the
    defaults of every hook (`Algorithm`)."""

    alpha0: float = 0.1
    beta: float = 1.0
    schedule: str = "sqrt"

    name: ClassVar[str]  # each algorithm's own
    messages: ClassVar[tuple[str, ...]] = ()
    # how it mixes what it hears: (L(k) x)_i ("laplacian") or Metropolis weights ("metropolis"); the mean of that
    # mixing sets its fixed point when a channel loses messages (`dgtd.channels.lossy`)
    mixing: ClassVar[str] = "laplacian"

    def __post_init__(self):
        check_schedule(self.schedule, self.alpha0, self.beta)

    def sends(self, state) -> dict:
        """What each agent sends at step k: nothing, for an algorithm without ``messages``."""
        return {}

    def estimate(self, state) -> np.ndarray:
        """The value-function weights: ``state.w`` for every algorithm of dgtd."""
        return state.w

    def fixed_point(self, moments, mean_laplacian, w_star: np.ndarray) -> FixedPoint:
        """w* = A^-1 b_mean for every agent: the fixed point of every method here that solves the average reward's
        projected Bellman equation (Proposition 1), when it mixes with a symmetric mean Laplacian (its ``mixing``'s,
        `dgtd.run.loop.prepare`); with an asymmetric one (messages lost more one way than the other), the w* of the
        rewards weighted by its left null vector (`dgtd.problems.exact.weighted_w_star`)."""
        from dgtd.problems import exact

        return FixedPoint(exact.weighted_w_star(moments, mean_laplacian, w_star)[None, :])

    def prepare(self, moments, network, fixed: FixedPoint) -> tuple:
        return self, {}

    def diagnostics(self, state, moments, mean_laplacian) -> dict:
        return {}

    def describe(self) -> str:
        return f"{self.name}: " + ", ".join(f"{k} {v}" for k, v in asdict(self).items() if v is not None)


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
