"""The first stage of a run (`plan_run`): the pieces checked to fit, the exact references computed (`prepare`), the
layout and its kernel chosen, the source of the samples made: a `Plan`, everything about a run that does not change
while it runs."""

from __future__ import annotations

import threading
import time
import weakref
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from dgtd.algorithms.base import FixedPoint, check_contract
from dgtd.channels import Arcs, Perfect
from dgtd.errors import DgtdInputError
from dgtd.graphs.random import RandomEdges
from dgtd.problems import exact
from dgtd.problems.model import Problem, chain_period
from dgtd.run.layout import layout_for, spread_over
from dgtd.run.measure import DIVERGENCE_FACTOR
from dgtd.run.memory import SUM_TRACE_MAX, TRACE_MAX, available_bytes, check_memory
from dgtd.run.settings import RunSettings, block_steps, checkpoint_steps, kept_steps, tail_steps
from dgtd.sources.model import ModelSource, SamplerTables, Sampling


@dataclass
class Context:
    """Everything a kernel reads: model arrays, sampler tables, network and its arcs, the algorithm as it runs (its
    `prepare`d form) and the channel between the agents; built once per run."""

    problem: Problem
    network: RandomEdges
    algorithm: Any
    sampling: Sampling
    tables: SamplerTables
    arcs: Arcs
    tail_start: int
    channel: Any = field(default_factory=Perfect)

    def __post_init__(self):
        p = self.problem
        self.Phi, self.gamma, self.ratio, self.R_sample = p.Phi, p.gamma, p.ratio, p.R_sample
        self.continuing = None if p.terminal is None else p.continuing  # None: every transition discounts by gamma
        self.sigma, self.reward_noise = p.sigma, p.reward_noise
        self.n_states, self.n_agents = p.n_states, p.n_agents


_MODEL_CACHE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _model_tables(problem: Problem):
    """The problem's `Moments` and sampler tables, built once per problem object and reused by every run on
    it (comparisons run several algorithms on one problem; the tables of a 400-state MDP take seconds)."""
    if not isinstance(problem, Problem):  # an estimated reference (`dgtd.problems.reference`): no model to sample
        return problem.moments, None
    if problem not in _MODEL_CACHE:
        moments = exact.Moments(problem)
        _MODEL_CACHE[problem] = interruptible(lambda: (moments, SamplerTables.build(problem, moments.d)))
    return _MODEL_CACHE[problem]


def interruptible(compute):
    """``compute()`` in a worker thread, the caller waiting in short steps: a long LAPACK call does not look at
    Ctrl-C, but the waiting thread does, so the interrupt is taken at once (the worker is left to the process's
    exit)."""
    box = {}

    def work():
        try:
            box["value"] = compute()
        except BaseException as e:  # noqa: BLE001  (handed to the caller)
            box["error"] = e

    worker = threading.Thread(target=work, daemon=True, name="dgtd-exact")
    worker.start()
    while worker.is_alive():
        worker.join(0.1)
    if "error" in box:
        raise box["error"]
    return box["value"]


class Reference(NamedTuple):
    """What a run measures against, and the context its kernels read (`prepare`)."""

    ctx: Context
    moments: Any  # `dgtd.problems.exact.Moments`, or an estimated reference's
    L_mean: Any  # the mean mixing Laplacian (dense or sparse)
    fixed: FixedPoint  # what the errors are measured against
    report: dict  # what the algorithm reports of itself
    w_star: np.ndarray
    tail_window: int


def prepare(
    problem: Problem, network: RandomEdges, algorithm, sampling: Sampling, settings: RunSettings, channel=None
) -> Reference:
    """Check that the pieces fit and compute the exact reference quantities (``channel``: `Perfect` by default)."""
    if network.n_nodes != problem.n_agents:
        raise DgtdInputError(
            f"the network has {network.n_nodes} agents but the problem has {problem.n_agents} (rows of R); make them "
            "agree"
        )
    if problem.reward_noise not in ("none", "transition") and (problem.R_sample.min() < 0 or problem.R.min() < 0):
        raise DgtdInputError(
            "reward noise draws rewards in [0, sigma] but this problem has negative mean rewards; "
            "use --reward-noise none"
        )
    if isinstance(problem, Problem) and sampling.mode == "markov" and chain_period(problem.P_behaviour) > 1:
        raise DgtdInputError(
            "the behaviour chain is periodic, so Markovian samples never settle to d; use i.i.d. sampling "
            "(--sampling iid)"
        )
    moments, tables = _model_tables(problem)
    arcs = Arcs.of(network.base.edges, network.n_nodes)
    channel = Perfect() if channel is None else channel
    L_mean = mean_mixing(network, channel, arcs, algorithm)
    w_star = exact.w_star(moments)
    fixed = algorithm.fixed_point(moments, L_mean, w_star)  # what the errors are measured against
    algorithm, report = algorithm.prepare(moments, network, fixed)  # the algorithm as it runs here (DGTD's boxes)
    if fixed_point_unknown(network, channel, algorithm):
        report = {**report, "fixed_point": FIXED_POINT_UNKNOWN.format(n=exact.DENSE_N)}
    elif not getattr(channel, "linear", True) and algorithm.messages:
        report = {**report, "fixed_point": FIXED_POINT_NONLINEAR}
    T = int(settings.iterations)
    tail_window = tail_steps(T, settings.tail_fraction)
    ctx = Context(problem, network, algorithm, sampling, tables, arcs, T - tail_window, channel)
    return Reference(ctx, moments, L_mean, fixed, report, w_star, tail_window)


FIXED_POINT_UNKNOWN = (
    "not computed: where messages are lost, the fixed point is solved densely, for at most {n} agents; the errors "
    "are against w*, which the run may not reach"
)


FIXED_POINT_NONLINEAR = (
    "not computed: top-k without error feedback drops the smaller coordinates, a choice that depends on the values, "
    "so the mean dynamics are not linear; the errors are against the fixed point of the links without it"
)


def fixed_point_unknown(network, channel, algorithm) -> bool:
    """Whether the fixed point of a run over links other than the perfect ones (whose mean mixing is the channel's
    own) is beyond what `mean_mixing` computes (more than DENSE_N agents, or a network without edge probabilities,
    such as a simulator's proximity links)."""
    own_mixing = not isinstance(channel, Perfect) and bool(algorithm.messages)
    return own_mixing and (network.n_nodes > exact.DENSE_N or not hasattr(network, "p"))


def mean_mixing(network, channel, arcs: Arcs, algorithm):
    """E of the mixing Laplacian ``algorithm`` applies to what it hears over ``channel``: the network's mean
    Laplacian (symmetric: each link up both ways at once) or, for an algorithm that communicates, the channel's
    (`dgtd.channels.base.Channel.mean_mixing`: the mean of what is heard, by the algorithm's ``mixing``; asymmetric
    where a link loses more one way than the other). Its fixed point follows from it
    (`dgtd.problems.exact.weighted_w_star`)."""
    sparse = network.n_nodes > exact.DENSE_N  # O(N + |E|) memory for many agents
    if not algorithm.messages or not hasattr(network, "p") or sparse:
        return network.mean_laplacian(sparse=sparse)  # (under loss beyond DENSE_N agents: `fixed_point_unknown`)
    return channel.mean_mixing(network, arcs, algorithm.mixing)


@dataclass(frozen=True, eq=False)
class Plan:
    """Everything about a run that does not change while it runs: its settings and checkpoint ``steps``, the context
    its kernels read, the references it measures against, its layout (with the kernel) and source of samples, the
    blocks it advances by."""

    settings: RunSettings
    steps: np.ndarray  # the checkpoint steps (`checkpoint_steps`)
    reference: Reference
    layout: Any  # `dgtd.run.layout.Whole` or the MPI runtime's `Ranks`
    source: Any
    fused: bool  # the kernel draws its own samples from the source's keyed streams
    block: int  # steps a block at most
    every: int  # steps between saved checkpoints (0: none)
    limit: float  # an estimate above this has diverged
    estimates: int  # the whole run's estimates: one per agent, or 1 for a centralised learner
    keep_trace: bool  # every agent's estimate is kept at every checkpoint (a small run's trajectory)
    # the running sum at every checkpoint is kept, for the tail average at each (`tail_at`): up to 160 MB (it is not
    # saved with the results, unlike the trace), else the tail metrics are NaN
    keep_sums: bool
    w_ref_held: np.ndarray  # the fixed point's rows of the agents held here
    t_start: float = field(default_factory=time.perf_counter)

    @property
    def ctx(self) -> Context:
        return self.reference.ctx

    @property
    def algorithm(self):
        """The algorithm as it runs (its `prepare`d form: DGTD's boxes)."""
        return self.reference.ctx.algorithm

    @property
    def moments(self):
        return self.reference.moments

    @property
    def n_agents(self) -> int:
        return self.reference.ctx.n_agents

    def relative_error(self, w: np.ndarray) -> np.ndarray:
        """|w_i - w_ref,i|_inf / |w_ref|_inf of each agent held here (B, n)."""
        return exact.relative_error(w, self.w_ref_held, of=self.reference.fixed.w)

    def value_error(self, w: np.ndarray) -> np.ndarray:
        """|Phi (w_i - w_ref,i)|_d / |Phi w_ref|_d of each agent held here (B, n)."""
        return exact.value_error(self.moments, w, self.w_ref_held, of=self.reference.fixed.w)


def run_steps(settings: RunSettings, resume: dict | None = None) -> np.ndarray:
    """The steps a run measures at (`checkpoint_steps`, or a resumed run's: `kept_steps`)."""
    T = int(settings.iterations)
    return kept_steps(checkpoint_steps(T, int(settings.checkpoints)), T, resume)


def plan_run(
    problem: Problem,
    network: RandomEdges,
    algorithm,
    sampling: Sampling,
    settings: RunSettings,
    source=None,
    channel=None,
    checkpoint_every: int = 0,
    resume: dict | None = None,
) -> Plan:
    """A run's `Plan`: its memory checked, its references computed, its source made (the problem's model by default),
    its layout chosen (``resume``: the snapshot it continues, whose message ages an asynchronous layout takes up)."""
    t_start = time.perf_counter()
    steps = run_steps(settings, resume)
    B, N, q = int(settings.seeds), problem.n_agents, problem.n_features
    check_contract(algorithm)  # before anything compiles
    ranks, here, free = spread_over(algorithm, available_bytes())
    check_memory(algorithm, B, N, q, 2 * network.n_edges, len(steps), settings.backend, ranks, here, free)
    reference = prepare(problem, network, algorithm, sampling, settings, channel)
    ctx = reference.ctx
    source = model_source(ctx, settings) if source is None else source
    if checkpoint_every > 0 and not getattr(source, "resumable", True):
        raise DgtdInputError(
            "this run's samples come from a simulator whose state cannot be saved, so it cannot be "
            "resumed from a checkpoint: leave out --checkpoint-every (checkpoint_every)"
        )
    layout = layout_for(ctx, settings, resume)
    source = layout.local(source)  # a rank draws the numbers of its agents and their neighbours only
    # Kernels that draw their own samples (`Draws`) materialise nothing: their blocks are bounded by work (a few
    # seconds between progress updates), not by the memory of a block of samples.
    fused = getattr(layout.kernel, "draws_samples", False) and isinstance(source, ModelSource)
    if fused:
        block = block_steps(settings.block_size, N, 0, B, budget=layout.block_budget)
    else:
        block = block_steps(settings.block_size, N, network.n_edges, B)
    w0_norm = 0.0 if problem.w0 is None else float(np.abs(problem.w0).max())
    estimates = N if ctx.algorithm.estimate(ctx.algorithm.init(1, 2, 1)).shape[1] == 2 else 1  # (1: centralised)
    return Plan(
        settings=settings,
        steps=steps,
        reference=reference,
        layout=layout,
        source=source,
        fused=fused,
        block=block,
        every=int(checkpoint_every),
        limit=DIVERGENCE_FACTOR * max(1.0, float(np.abs(reference.w_star).max()), w0_norm),
        estimates=estimates,
        keep_trace=B * estimates * q * len(steps) <= TRACE_MAX,
        keep_sums=B * estimates * q * len(steps) <= SUM_TRACE_MAX,
        w_ref_held=layout.rows(reference.fixed.w),
        t_start=t_start,
    )


def model_source(ctx: Context, settings: RunSettings) -> ModelSource:
    """Samples drawn from the problem's model, or a one-line error where it has none."""
    if ctx.tables is None:
        raise DgtdInputError(
            f"{ctx.problem.name} has no model to draw samples from; pass its simulator or data as the source"
        )
    seeds = range(int(settings.seeds))
    return ModelSource(ctx.problem, ctx.network, ctx.sampling, ctx.tables, settings.seed, seeds, settings.backend)
