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
- ``from_the_problem(moments, network) -> (algorithm, note)``: its first step from its mean dynamics on a model
  (`dgtd.algorithms.mean_dynamics`), where no step option is given;
- ``diagnostics(state, moments, mean_laplacian) -> dict``: numbers reported after a run (DGTD's KKT residuals);
- ``describe() -> str``: one line for the command line.

**One definition of the arithmetic.** An algorithm's step is written once, as plain arithmetic that a float, a NumPy
array and a JAX array all accept (as rlax and optax write theirs), in pure functions of its class, so that the NumPy
reference (`StepSizes.update`: arrays (B, N, q) broadcast against (B, N, 1)), the compiled driver (one agent, a loop
over the features: `dgtd.backends.compiled.step`) and JAX (`dgtd.backends.jax`) all run the same lines:

- ``reads``: the products phi(s)^T x and phi(s')^T x the step reads, as pairs ("phi" or "phi_next", a field);
- ``coefficients(p, dots, r, ratio, gamma) -> tuple``: per transition, the scalars its directions are made of
  (``dots`` in the order of ``reads``: TD errors and the like);
- ``terms(p, phi, phi_next, c, gamma) -> tuple``: per transition and feature, its sample directions, linear in
  (phi_f(s), phi_f(s')) so that they vanish where both do (the compiled driver skips them there on sparse features);
  a centralised learner (``centralised``) averages them over the N transitions the agents observed;
- ``feature(p, x, heard, d, steps) -> tuple``: per agent and feature, the new state ``x`` (its fields in order) from
  the old, what it heard (``heard``: the aggregate of each message, Laplacian or Metropolis as its ``mixing`` says),
  the directions ``d`` and the step sizes (`StepSizes.steps`: alpha_k, and whatever else it derives from it);
- ``transmit(x) -> tuple``: per agent and feature, its messages from its state.

``p`` is the algorithm's `StepSizes.params`, a NamedTuple of floats. The state's fields list what an agent keeps to
itself first and then what it sends (a message named as a field is that field), so that the compiled driver finds
them without a table. Helpers the functions call (`clip`, `dgtd.algorithms.gtd2.aux_step`) are plain functions too,
which the compiled backend compiles with them.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any, ClassVar, NamedTuple, Protocol

import numpy as np

from dgtd.algorithms.stepsizes import check_schedule
from dgtd.errors import DgtdInputError
from dgtd.fields import option
from dgtd.samples import Sample, discount, namespace  # noqa: F401  (discount: algorithms read it here)


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


class NoParams(NamedTuple):
    """No hyperparameter the arithmetic reads (beyond the step sizes)."""


@dataclass(frozen=True)
class StepSizes:
    """The step sizes alpha_k (`dgtd.algorithms.stepsizes`): ``alpha0``, ``beta`` and the ``schedule``; and the
    defaults of every hook (`Algorithm`)."""

    alpha0: float = field(
        default=0.1,
        metadata=option(
            "Step-size scale alpha0 (DGTD's 10 suits features of unit scale: lower it in proportion to |phi(s)|^2)."
        ),
    )
    beta: float = field(default=1.0, metadata=option("Step-size offset beta in alpha0/sqrt(k+beta)."))
    schedule: str = field(
        default="sqrt", metadata=option("alpha0/sqrt(k+beta) (the paper's), alpha0/(k+beta), or constant alpha0.")
    )

    name: ClassVar[str]  # each algorithm's own
    messages: ClassVar[tuple[str, ...]] = ()
    # how it mixes what it hears: (L(k) x)_i ("laplacian") or Metropolis weights ("metropolis"); the mean of that
    # mixing sets its fixed point when a channel loses messages (`dgtd.channels.lossy`)
    mixing: ClassVar[str] = "laplacian"

    def __post_init__(self):
        check_schedule(self.schedule, self.alpha0, self.beta)

    reads: ClassVar[tuple[tuple[str, str], ...]] = ()
    centralised: ClassVar[bool] = False  # one learner that averages the N transitions' directions
    Params: ClassVar[Any] = NoParams  # a NamedTuple type: what `params` hands the arithmetic

    def params(self) -> tuple:
        """``p``, what the arithmetic reads of the hyperparameters: the fields of ``Params``, as floats."""
        return self.Params(*(float(getattr(self, f)) for f in self.Params._fields))

    @staticmethod
    def steps(p, alpha):
        """The step sizes of step k from alpha_k: alpha_k alone by default."""
        return (alpha,)

    @staticmethod
    def coefficients(p, dots, r, ratio, gamma) -> tuple:
        """Per transition, the scalars its directions are made of (each algorithm's own)."""
        raise NotImplementedError

    @staticmethod
    def terms(p, phi, phi_next, c, gamma) -> tuple:
        """Per transition and feature, its sample directions (each algorithm's own)."""
        raise NotImplementedError

    @staticmethod
    def feature(p, x, heard, d, steps) -> tuple:
        """Per agent and feature, the new state (each algorithm's own)."""
        raise NotImplementedError

    @staticmethod
    def transmit(x) -> tuple:
        """What an agent sends, from its state: nothing, for an algorithm without ``messages``."""
        return ()

    def sends(self, state) -> dict:
        """What each agent sends at step k (name -> (B, N, q)): ``transmit`` of its state."""
        return dict(zip(self.messages, self.transmit(tuple(state))))

    def directions(self, state, sample: Sample) -> tuple:
        """The sample directions ``d`` of every seed and agent (B, N, q), or of the learner (B, 1, q): ``terms`` of the
        ``coefficients`` of the products it ``reads``, averaged over the N transitions for a centralised learner."""
        xp = namespace(sample.phi)
        p = self.params()
        features = {"phi": sample.phi, "phi_next": sample.phi_next}
        dots = tuple(dot(features[f], getattr(state, x), xp) for f, x in self.reads)
        c = self.coefficients(p, dots, sample.r, sample.ratio, sample.gamma)
        d = self.terms(p, sample.phi, sample.phi_next, tuple(xp.asarray(x)[..., None] for x in c), discount(sample))
        if self.centralised:
            d = tuple(agent_mean(x, sample.r.shape[1], xp) for x in d)
        return d

    def update(self, state, sample: Sample, inbox, alpha: float):
        """One step of every seed and agent from the algorithm's one definition (the module's docstring): its
        ``directions`` and what each agent heard, through its ``feature`` on whole arrays."""
        return self.moved(state, self.directions(state, sample), inbox, alpha)

    def moved(self, state, directions: tuple, inbox, alpha: float):
        """The state moved along ``directions`` (its ``directions`` of one sample, or their mean over several: a
        mini-batch) and by what each agent heard in ``inbox``, through its ``feature``."""
        heard = tuple(getattr(inbox, self.mixing)(m) for m in self.messages)
        p = self.params()
        return type(state)(*self.feature(p, tuple(state), heard, directions, self.steps(p, alpha)))

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

    def from_the_problem(self, moments, network) -> tuple:
        """(this algorithm with its first step at most what its mean dynamics on the model allow, the header's line
        saying so or ""): `dgtd.algorithms.mean_dynamics.from_the_problem`, one rule for every method."""
        from dgtd.algorithms.mean_dynamics import from_the_problem

        return from_the_problem(self, moments, network)

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


def clip(x, bound):
    """Projection onto [-bound, bound] (Algorithm 1 line 9); NaN stays NaN. A method of NumPy's and JAX's arrays alike
    (the compiled backend compiles `dgtd.backends.compiled.step.clip` in its place)."""
    return x.clip(-bound, bound)


def dot(x, y, xp=np):
    """x_n^T y_n over the last axis of (B, n, q) arrays, broadcasting n = 1 against n = N."""
    return xp.einsum("bnq,bnq->bn", *xp.broadcast_arrays(x, y))


def agent_mean(x, n_agents: int, xp=np):
    """Mean over the agent axis of per-agent terms (B, N or 1, q), keeping it: a centralised learner's minibatch."""
    return xp.broadcast_to(x, (x.shape[0], n_agents, x.shape[2])).mean(axis=1, keepdims=True)


def td_error(dot_phi_next_w, dot_phi_w, r, gamma):
    """delta = r + gamma phi'^T w - phi^T w, from the two products: floats, or arrays (B, N)."""
    return r + gamma * dot_phi_next_w - dot_phi_w


def check_contract(algorithm) -> None:
    """What the run loop and every backend rely on, checked in one line before anything compiles: a NamedTuple state
    of (B, N or 1, q) arrays with a field w, whose fields list what an agent keeps before what it sends, and messages
    that ``sends`` names as ``messages`` does."""
    name = getattr(algorithm, "name", type(algorithm).__name__)
    state = algorithm.init(2, 3, 4)
    fields = tuple(getattr(state, "_fields", ()))
    if not fields:
        raise DgtdInputError(f"{name}'s init returns a {type(state).__name__}, not a NamedTuple of arrays")
    if "w" not in fields:
        raise DgtdInputError(f"{name}'s state has no field w (the value weights every estimate reports)")
    odd = [f for f, x in zip(fields, state) if np.shape(x) not in ((2, 3, 4), (2, 1, 4))]
    if odd:
        raise DgtdInputError(
            f"{name}'s state field {odd[0]} is not (B, N or 1, q): init(2, 3, 4) gave it the shape "
            f"{np.shape(state[fields.index(odd[0])])}"
        )
    sent = tuple(algorithm.sends(state))
    if sent != tuple(algorithm.messages):
        raise DgtdInputError(f"{name} sends {sent}, not its messages {tuple(algorithm.messages)}")
    own = tuple(f for f in fields if f not in algorithm.messages)
    if fields[: len(own)] != own:
        raise DgtdInputError(f"{name}'s state {fields} lists what it sends before what it keeps")
