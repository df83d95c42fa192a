"""A run: named stages over one run state (`dgtd.run.state.RunState`).

    plan = plan_run(...)                 # problem, network, channel, algorithm, source, layout, references
    rs = start(plan, resume)             # the run state: fresh, or continued from a checkpoint
    load_kernel(plan, rs)                # the kernel compiled or loaded, before the first step
    while rs.k < T:
        rs = advance(plan, rs, until(plan, rs))   # draw -> deliver -> step, one block; seeds that diverge stopped
        if rs.k == steps[rs.c]:
            rs = record(plan, rs)         # the metrics at a checkpoint (`dgtd.run.measure`)
        save(plan, rs, on_checkpoint)     # the run state, every ``checkpoint_every`` steps
    return results(plan, rs)             # every agent's rows on the writing process, and the results

The layout (one process, or ranks of an MPI job) does what concerns the agents' placement: the kernel, the share of
the samples, the worst agent and ordered sums over the ranks, who writes (`dgtd.run.layout`); the run names no MPI.
A new kind of run is another composition of these stages.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from dgtd.algorithms.base import FixedPoint
from dgtd.algorithms.stepsizes import step_sizes
from dgtd.graphs.random import RandomEdges, as_network
from dgtd.problems import exact
from dgtd.problems.model import Problem
from dgtd.run.checkpoint import assemble
from dgtd.run.layout import kernel_for
from dgtd.run.measure import COUNTS, METRICS, measure, stop_diverged, stopped, tail_at
from dgtd.run.plan import (
    Context,
    Plan,
    fixed_point_unknown,
    interruptible,
    mean_mixing,
    plan_run,
    prepare,
)
from dgtd.run.settings import BACKENDS, MAX_COUNT, RunSettings, block_steps, check_count, checkpoint_steps
from dgtd.run.state import RunState, gathered, restore, snapshot
from dgtd.samples import Block
from dgtd.sources.model import ModelSource, Sampling


@dataclass
class RunResult:
    """What a run produced; arrays are indexed [checkpoint, seed, agent, feature] where they have those axes."""

    steps: np.ndarray
    metrics: dict
    agent_error_last: np.ndarray
    agent_error_avg: np.ndarray
    w_trace: np.ndarray | None
    w_last: np.ndarray
    w_avg: np.ndarray
    w_tail: np.ndarray
    tail_window: int
    w_star: np.ndarray
    fixed: FixedPoint
    final_state: dict
    seconds: float
    info: dict = field(default_factory=dict)
    # What the algorithm reports of itself (its hooks `fixed_point`, `prepare` and `diagnostics`): DGTD's theta*, mu*,
    # projection boxes and KKT residuals; summary.json carries it
    report: dict = field(default_factory=dict)
    # Where the per-agent arrays hold only this rank's agents (a spread run too large to gather: `GATHER_MAX`): the
    # run's layout, whose ``agents`` are their ids and whose methods combine over the ranks; None: every agent's rows
    rows: Any = None

    @property
    def w_ref(self) -> np.ndarray:
        """What the errors are measured against, (N or 1, q): the algorithm's fixed point, w* for every agent unless
        it converges elsewhere (DGTD with rho > 0: the regularised saddle point, info["regularisation_shift"]; any
        method over links that lose messages: `mean_mixing`)."""
        return self.fixed.w


def run(
    problem: Problem,
    network: RandomEdges,
    algorithm,
    sampling: Sampling = Sampling(),
    settings: RunSettings = RunSettings(),
    progress=None,
    source=None,
    *,
    checkpoint_every: int = 0,
    on_checkpoint=None,
    resume: dict | None = None,
    kernel_ready=None,
    channel=None,
    on_measured=None,
) -> RunResult:
    """Run ``algorithm`` for ``settings.seeds`` seeds at once; ``progress(n_steps)`` is called after each block.

    ``source`` supplies the samples (default: a `ModelSource` drawing from the problem's model); a simulator
    with hidden state or position-dependent networks passes its own. ``channel`` delivers what the agents send
    (default `dgtd.channels.Perfect`; `dgtd.channels.Lossy` loses messages).

    ``kernel_ready(seconds)`` is called once the block kernel is loaded, or compiled the first time on a machine
    (an empty block runs first, which changes nothing), with the seconds that took, before the first iteration:
    so a progress bar started then does not count the compilation into its first step.

    With ``checkpoint_every`` = K > 0, ``on_checkpoint(snapshot)`` is called at every multiple of K and at T with
    the run's whole state (`dgtd.run.state.snapshot`). Passing a snapshot as ``resume`` continues from it; the
    samples are a function of the step only, so the result equals that of an uninterrupted run bit for bit. A
    snapshot taken at the end of a run of fewer steps extends that run: its checkpoints are kept and a run of T
    steps' follow (`dgtd.run.plan.run_steps`); every iterate, average and count equals a run of T steps', and so does
    the tail average where the tail of T steps begins at or after the snapshot's step.

    ``on_measured(steps, metrics)`` is called as each checkpoint is measured, with the steps measured so far (c,) and
    each metric's values there (c, seeds), so that what was measured can be kept before the run ends.
    """
    plan = plan_run(problem, network, algorithm, sampling, settings, source, channel, checkpoint_every, resume)
    rs = start(plan, resume)
    kernel_seconds = load_kernel(plan, rs)
    if kernel_ready is not None:
        kernel_ready(kernel_seconds)
    t_loop, cpu_loop = time.perf_counter(), time.process_time()
    while rs.k < plan.settings.iterations:
        k = rs.k
        rs = advance(plan, rs, until(plan, rs))
        if progress is not None:
            progress(rs.k - k)
        if rs.k == plan.steps[rs.c]:
            rs = record(plan, rs)
            if on_measured is not None:
                on_measured(plan.steps[: rs.c], {m: v[: rs.c] for m, v in rs.metrics.items()})
            if not (rs.diverged_at < 0).any():  # every seed has diverged: nothing left to run
                stopped(rs)
                break
        save(plan, rs, on_checkpoint)
    timing = {
        "loop_seconds": time.perf_counter() - t_loop,  # the steps and their metrics (not the results gathered after)
        "loop_cpu_seconds": time.process_time() - cpu_loop,
        "kernel_seconds": kernel_seconds,
    }
    return results(plan, rs, timing)


def start(plan: Plan, resume: dict | None = None) -> RunState:
    """The run state at step 0 (the source started), or the one ``resume`` saved (the source set to its state)."""
    settings, ctx, layout = plan.settings, plan.ctx, plan.layout
    B, N, q, C = int(settings.seeds), plan.n_agents, ctx.problem.n_features, len(plan.steps)
    state = plan.algorithm.init(B, N if layout.agents is None else len(layout.agents), q)
    if ctx.problem.w0 is not None:  # the task's prescribed start (Baird's); every state names the value weights w
        state = state._replace(w=np.broadcast_to(ctx.problem.w0, state.w.shape).copy())
    n_est = plan.algorithm.estimate(state).shape[1]  # the agents' estimates held here, or 1 for a centralised learner
    rs = RunState(
        state=state,
        steps=plan.steps,
        # Kernels keep one running sum of w_k; the tail average is its difference from a copy taken at tail_start (a
        # block boundary), so no kernel reads or writes a second sum.
        sums={"all": np.zeros((B, n_est, q))},
        metrics={m: np.zeros((C, B)) for m in METRICS},
        counts={m: np.zeros((C, B)) for m in COUNTS},
        agent_error_last=np.zeros((C, B, n_est)),
        agent_error_avg=np.zeros((C, B, n_est)),
        w_trace=np.zeros((C, B, plan.estimates, q)) if plan.keep_trace and layout.root else None,  # (rank 0 gathers)
        sum_trace=np.zeros((C, B, n_est, q)) if plan.keep_sums else None,
        # the channel's counts, frozen for a seed once it diverges (a stopped seed sends nothing)
        messages=np.zeros(B),
        bits=np.zeros(B),
        per_arc=np.zeros((B, 0)),  # how often each arc delivered, where the channel counts it (`Imperfect`)
        diverged_at=np.full(B, -1, dtype=np.int64),
        channel=layout.init_channel(ctx.channel, B, settings.seed),
    )
    if resume is None:
        plan.source.start()
        return rs
    trajectories = getattr(plan.source, "state_agents", None)  # a rank's Markov chains
    resume = assemble(resume, N, ctx.arcs.n_arcs, layout.agents, layout.arc_ids, trajectories)
    plan.source.set_state(resume["source"])
    rs = restore(rs, resume)
    if rs.k <= ctx.tail_start:  # (a finished run extended: its tail begins again, at or after the step it ended at)
        rs = replace(rs, tail_base=None)
    return replace(rs, steps=plan.steps)


def load_kernel(plan: Plan, rs: RunState) -> float:
    """Seconds to load the kernel, or compile it the first time on a machine: an empty block runs, which changes
    nothing (not inside the first step, where it would look like a stalled run). A simulator's agents each observe
    their own state."""
    t = time.perf_counter()
    source, ctx = plan.source, plan.ctx
    if isinstance(source, ModelSource):
        empty = source.draws(0) if plan.fused else source.next_block(0)
    else:
        empty = Block.empty(rs.diverged_at.shape[0], plan.n_agents, plan.n_agents, ctx.network.n_edges)
    plan.layout.kernel(ctx, rs.state, rs.channel, rs.w_sum, np.zeros(0), empty)
    return time.perf_counter() - t


def until(plan: Plan, rs: RunState) -> int:
    """The step the next block ends at: a block's length, the next checkpoint, the next save, or the tail's start."""
    k, T, every, tail_start = rs.k, int(plan.settings.iterations), plan.every, plan.ctx.tail_start
    return min(
        k + plan.block,
        int(plan.steps[rs.c]),
        (k // every + 1) * every if every else T,
        tail_start if k < tail_start else T,
    )


def advance(plan: Plan, rs: RunState, k1: int) -> RunState:
    """Steps k .. k1 - 1: the block's samples drawn, the messages delivered and every agent stepped by the layout's
    kernel; the channel's counts of the live seeds kept, and seeds that diverged stopped."""
    k, algorithm, source = rs.k, plan.algorithm, plan.source
    tail_base = rs.w_sum.copy() if k == plan.ctx.tail_start and rs.tail_base is None else rs.tail_base
    blk = source.draws(k1 - k) if plan.fused else source.next_block(k1 - k)
    alphas = step_sizes(algorithm.schedule, algorithm.alpha0, algorithm.beta, k, k1)
    with np.errstate(over="ignore", invalid="ignore"):  # a diverging seed is detected below, not warned about
        state, channel, w_sum = plan.layout.kernel(plan.ctx, rs.state, rs.channel, rs.w_sum, alphas, blk)
    live = rs.diverged_at < 0
    per_arc = rs.per_arc
    if plan.ctx.channel.holds and channel.per_arc.size:
        per_arc = np.where(live[:, None], channel.per_arc, per_arc if per_arc.size else channel.per_arc)
    limit, any_ = plan.limit, plan.layout.any
    state, sums = stop_diverged(state, {"all": w_sum}, algorithm.estimate(state), limit, rs.diverged_at, k1, any_)
    return replace(
        rs,
        k=k1,
        state=state,
        sums=sums,
        channel=channel,
        tail_base=tail_base,
        messages=np.where(live, channel.messages, rs.messages),
        bits=np.where(live, channel.bits, rs.bits),
        per_arc=per_arc,
    )


def record(plan: Plan, rs: RunState) -> RunState:
    """The metrics of checkpoint c at its step (`dgtd.run.measure.measure`), then the next checkpoint."""
    measure(plan, rs)
    return replace(rs, c=rs.c + 1)


def save(plan: Plan, rs: RunState, on_checkpoint) -> None:
    """At every multiple of ``checkpoint_every``, and at T (where a finished run is extended to more steps from): the
    run state to ``on_checkpoint`` (`snapshot`). The source's state and the message ages are taken on every process,
    saving or not (collectives where the agents are spread)."""
    if not (plan.every and (rs.k % plan.every == 0 or rs.k == plan.settings.iterations)):
        return
    ages = plan.layout.message_ages()
    rs = replace(
        rs,
        source=plan.source.get_state(),  # (a rank's source holds its own agents)
        message_ages={n: ages[n] for n in ("counts", "transit")} if ages else None,
    )
    if on_checkpoint is not None:
        on_checkpoint(snapshot(rs, plan.layout, rs.seconds + time.perf_counter() - plan.t_start))


GATHER_MAX = 1_000_000  # seeds x agents x features of a spread run's final iterates that rank 0 gathers at most


def by_rank(plan: Plan) -> bool:
    """Whether a spread run's per-agent results stay on the ranks that hold them (each rank writes its agents' rows:
    `dgtd.run.results`): where its final iterates pass `GATHER_MAX` numbers, so that rank 0 holds nothing of size N.
    The same verdict on every rank (sizes alone)."""
    B, q = int(plan.settings.seeds), plan.ctx.problem.n_features
    return plan.layout.agents is not None and plan.estimates > 1 and B * plan.n_agents * q > GATHER_MAX


def results(plan: Plan, rs: RunState, timing: dict) -> RunResult:
    """The `RunResult`: every agent's rows gathered on the process that writes (`gathered`), or left on their ranks
    (`by_rank`), the averaged and tail averaged iterates, what the algorithm reports of itself, the counts."""
    ref, ctx, layout, algorithm = plan.reference, plan.ctx, plan.layout, plan.algorithm
    T = int(plan.settings.iterations)
    spread = by_rank(plan)
    if not spread:
        rs = gathered(rs, layout, ctx.arcs.n_arcs, ctx.channel.holds)
    report = ref.report
    if spread:  # (the diagnostics take every agent's state: KKT residuals over the whole network)
        report = {**ref.fixed.report, **report}
    elif layout.root:
        report = {**ref.fixed.report, **report, **algorithm.diagnostics(rs.state, ref.moments, ref.L_mean)}
    tail_sum = np.nan if rs.tail_base is None else rs.tail_base
    return RunResult(
        steps=plan.steps,
        metrics=rs.metrics,
        agent_error_last=rs.agent_error_last,
        agent_error_avg=rs.agent_error_avg,
        w_trace=rs.w_trace,
        w_last=algorithm.estimate(rs.state),
        w_avg=rs.w_sum / T,
        w_tail=(rs.w_sum - tail_sum) / ref.tail_window,
        tail_window=ref.tail_window,
        w_star=ref.w_star,
        fixed=ref.fixed,
        final_state=rs.state._asdict(),
        report=report,
        seconds=rs.seconds + time.perf_counter() - plan.t_start,
        info=run_info(plan, rs, timing, spread),
        rows=layout if spread else None,
    )


def run_info(plan: Plan, rs: RunState, timing: dict, spread: bool = False) -> dict:
    """`RunResult.info`: the distribution d, the moments, the counts, the divergence steps and the timings."""
    ref, algorithm = plan.reference, plan.algorithm
    ages = plan.layout.message_ages()
    return {
        "d": ref.moments.d,
        "moments": ref.moments,
        "mspbe_w_star": float(exact.mspbe(ref.moments, ref.w_star)),
        "diverged_at": rs.diverged_at,
        "samples_per_step": plan.n_agents,
        "messages": rs.messages,
        "bits": rs.bits,
        "counts": rs.counts,
        "n_agents": plan.n_agents,
        **(per_agent_counts(plan.ctx, rs.per_arc) if plan.layout.root and not spread else {}),
        # how far DGTD's regularised saddle point (rho > 0) is from w* (|.|_inf relative); lost messages move the
        # fixed point too, which the results report as w_fixed
        "regularisation_shift": float(exact.relative_error(ref.fixed.w, ref.w_star).max())
        if getattr(algorithm, "rho", 0.0)
        else 0.0,
        **({"message_ages": ages} if ages else {}),
        **timing,
    }


def per_agent_counts(ctx, per_arc: np.ndarray) -> dict:
    """{"per_agent": {"messages", "bits"}}: what each agent sent that arrived (B, N), where the channel counts each
    arc's deliveries (`dgtd.channels.Imperfect`), else nothing."""
    if per_arc.size == 0:
        return {}
    M, q = len(ctx.algorithm.messages), ctx.problem.n_features
    sent = np.zeros((per_arc.shape[0], ctx.arcs.n_agents))
    np.add.at(sent, (slice(None), np.asarray(ctx.arcs.src, dtype=np.int64)), per_arc)  # type: ignore[arg-type]
    return {"per_agent": {"messages": sent * M, "bits": sent * M * ctx.channel.vector_bits(q)}}


def evaluate(
    problem: Problem,
    network: RandomEdges,
    algorithm,
    *,
    sampling: Sampling = Sampling(),
    iterations: int = RunSettings.iterations,
    seeds: int = RunSettings.seeds,
    seed: int = RunSettings.seed,
    backend: str = RunSettings.backend,
    channel=None,
    **settings,
) -> RunResult:
    """Run ``algorithm`` on ``problem`` over ``network``: `run` with its `RunSettings` given as keywords, and its
    ``channel`` (default `dgtd.channels.Perfect`).

    Example::

        >>> import dgtd
        >>> sc = dgtd.scenario("paper-example-1")
        >>> result = dgtd.evaluate(sc.problem, sc.network, dgtd.DGTD(alpha0=1.0), iterations=2000, seeds=2,
        ...                        backend="numpy")
        >>> result.w_last.shape  # (seeds, agents, features)
        (2, 5, 2)
    """
    return run(
        problem,
        as_network(network),  # (a bare graph: its fixed network; it raised AttributeError)
        algorithm,
        sampling,
        RunSettings(iterations=iterations, seeds=seeds, seed=seed, backend=backend, **settings),
        channel=channel,
    )


__all__ = [
    "BACKENDS",
    "COUNTS",
    "MAX_COUNT",
    "Context",
    "RunResult",
    "RunSettings",
    "Sampling",
    "block_steps",
    "check_count",
    "checkpoint_steps",
    "evaluate",
    "fixed_point_unknown",
    "interruptible",
    "kernel_for",
    "mean_mixing",
    "prepare",
    "run",
    "tail_at",
]
