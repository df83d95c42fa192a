"""The run loop: draws uniforms in blocks, advances a backend kernel, and records exact metrics at checkpoints."""

from __future__ import annotations

import time
import weakref
from dataclasses import dataclass, field

import numpy as np

from dgtd.algorithms.base import FixedPoint
from dgtd.algorithms.stepsizes import step_sizes
from dgtd.channels import Arcs, Perfect
from dgtd.errors import DgtdInputError
from dgtd.fields import option
from dgtd.graphs.random import RandomEdges
from dgtd.problems import exact
from dgtd.problems.model import Problem, chain_period
from dgtd.run.layout import Whole, reported
from dgtd.run.memory import SUM_TRACE_MAX, TRACE_MAX, check_memory
from dgtd.samples import Block
from dgtd.sources.model import ModelSource, SamplerTables, Sampling

BACKENDS = ("numpy", "numba", "jax")
DIVERGENCE_FACTOR = 1e6  # a seed has diverged when |w|_inf exceeds this times max(1, |w*|_inf, |w0|_inf)
# Counts recorded at every checkpoint beside the metrics (in RunResult.info["counts"], arrays (C, B)): agent-samples
# consumed, the messages (vectors of q numbers) and bits the channel delivered, 1 once diverged.
COUNTS = ("samples", "messages", "bits", "diverged")


@dataclass(frozen=True)
class RunSettings:
    """How long and how many: the only defaults of these fields in dgtd (`dgtd.config.RunLength`, the CLI and
    `dgtd compare` take theirs from here).

    - ``iterations`` T, ``seeds`` B run side by side, base ``seed`` (seed k draws with key (seed, k), `dgtd.streams`);
    - ``checkpoints``: about how many times metrics are recorded (`checkpoint_steps`);
    - ``tail_fraction``: the final fraction of the run averaged for w_tail;
    - ``block_size``: steps drawn and advanced per block (no effect on results);
    - ``backend``: one of `BACKENDS`, the compiled kernels, the NumPy reference or JAX (`dgtd.backends.jax`);
    - ``asynchronous``: agents spread over the ranks of an mpiexec job use the newest messages received from the
      other ranks, waiting only when the newest is more than ``staleness`` steps old (None: never; 0: the
      synchronous numbers) (`dgtd.backends.mailbox`); off, the ranks give one process's numbers bit for bit.
    """

    iterations: int = field(
        default=10_000,
        metadata=option("Number of iterations T (default: the scenario's).", flags=("--iterations", "-T")),
    )
    seeds: int = field(default=1, metadata=option("Independent runs, side by side."))
    seed: int = field(default=0, metadata=option("Base seed; seed k draws from the keyed streams of key (seed, k)."))
    checkpoints: int = field(
        default=200, metadata=option("How many times to record metrics (at most once per iteration).")
    )
    tail_fraction: float = field(default=0.5, metadata=option("Final fraction of the run averaged for w_tail."))
    block_size: int = field(default=4096, metadata=option("Steps drawn and advanced per block (no effect on results)."))
    backend: str = field(
        default="numba",
        metadata=option(
            "The compiled kernels (numba), the NumPy reference, or JAX on its device (the extra dgtd[jax]; perfect "
            "and lossy links): the same numbers."
        ),
    )
    asynchronous: bool = field(
        default=False,
        metadata=option(
            "Under mpiexec: ranks do not wait for each other's messages, each agent using the newest received (their "
            "ages are recorded); synchronous (the default) gives one process's numbers.",
            flags=("--asynchronous/--synchronous",),
        ),
    )
    staleness: int | None = field(
        default=None,
        metadata=option(
            "With --asynchronous: a rank waits for a neighbour's message once the newest it has is more than S steps "
            "old (default: never waits; 0: the synchronous numbers)."
        ),
    )

    def __post_init__(self):
        for name in ("iterations", "seeds", "checkpoints", "block_size"):
            object.__setattr__(self, name, check_count(name, getattr(self, name), 1))
        object.__setattr__(self, "seed", check_count("seed", self.seed, 0))
        if self.staleness is not None:
            object.__setattr__(self, "staleness", check_count("staleness", self.staleness, 0))
            if not self.asynchronous:
                raise DgtdInputError("staleness bounds the ages of an asynchronous run's messages: give --asynchronous")
        if not 0.0 < self.tail_fraction <= 1.0:
            raise DgtdInputError(f"tail_fraction must lie in (0, 1], got {self.tail_fraction}")
        if self.backend not in BACKENDS:
            raise DgtdInputError(f"backend must be one of {', '.join(BACKENDS)}, got {self.backend!r}")


MAX_COUNT = 2**63 - 1  # what a 64-bit integer (NumPy's, TOML's) holds


def check_count(name: str, value, low: int) -> int:
    """An integer setting in [low, 2^63 - 1] as an int (a whole float such as 1e5 too), or a one-line error naming
    it."""
    if isinstance(value, (float, np.floating)) and float(value).is_integer() and abs(value) < 2.0**63:
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not low <= value <= MAX_COUNT:
        raise DgtdInputError(f"{name} must be >= {low} and below 2^63, a whole number; got {value!r}")
    return int(value)


def checkpoint_steps(T: int, n: int) -> np.ndarray:
    """About n steps in 1..T, half evenly spaced and half log-spaced (for linear and log plots), T included. Any n
    from 2T on gives every step once, so n is capped there (a huge n would allocate for nothing)."""
    n = min(n, 2 * T)
    lin = np.linspace(0, T, n // 2 + 1)[1:]
    log = np.geomspace(1, T, n - n // 2)
    return np.unique(np.concatenate([np.round(lin), np.round(log), [T]]).astype(np.int64).clip(1, T))


@dataclass
class Context:
    """Everything a kernel reads: model arrays, sampler tables, network and its arcs, the algorithm as it runs (its
    `prepare`d form) and the channel between the agents; built once per run."""

    problem: Problem
    network: RandomEdges
    algorithm: object
    sampling: Sampling
    tables: SamplerTables
    arcs: Arcs
    tail_start: int
    channel: object = field(default_factory=Perfect)

    def __post_init__(self):
        p = self.problem
        self.Phi, self.gamma, self.ratio, self.R_sample = p.Phi, p.gamma, p.ratio, p.R_sample
        self.continuing = None if p.terminal is None else p.continuing  # None: every transition discounts by gamma
        self.sigma, self.reward_noise = p.sigma, p.reward_noise
        self.n_states, self.n_agents = p.n_states, p.n_agents


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

    @property
    def w_ref(self) -> np.ndarray:
        """What the errors are measured against, (N or 1, q): the algorithm's fixed point, w* for every agent unless
        it converges elsewhere (DGTD with rho > 0: the regularised saddle point, info["regularisation_shift"]; any
        method over links that lose messages: `mean_mixing`)."""
        return self.fixed.w


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
    import threading

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


def prepare(problem: Problem, network: RandomEdges, algorithm, sampling: Sampling, settings: RunSettings, channel=None):
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
    tail_window = max(1, int(np.ceil(settings.tail_fraction * T)))
    ctx = Context(problem, network, algorithm, sampling, tables, arcs, T - tail_window, channel)
    return ctx, moments, L_mean, fixed, report, w_star, tail_window


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
) -> RunResult:
    """Run ``algorithm`` for ``settings.seeds`` seeds at once; ``progress(n_steps)`` is called after each block.

    ``source`` supplies the samples (default: a `ModelSource` drawing from the problem's model); a simulator
    with hidden state or position-dependent networks passes its own. ``channel`` delivers what the agents send
    (default `dgtd.channels.Perfect`; `dgtd.channels.Lossy` loses messages).

    ``kernel_ready(seconds)`` is called once the block kernel is loaded, or compiled the first time on a machine
    (an empty block runs first, which changes nothing), with the seconds that took, before the first iteration:
    so a progress bar started then does not count the compilation into its first step.

    With ``checkpoint_every`` = K > 0, ``on_checkpoint(snapshot)`` is called at every multiple of K below T with
    the loop's whole state (`snapshot`: step, checkpoint index, algorithm state, running sums, metrics so far,
    the source's stream state). Passing a snapshot as ``resume`` continues from it; the samples are a
    function of the step only, so the result equals that of an uninterrupted run bit for bit.
    """
    t_start = time.perf_counter()
    steps = checkpoint_steps(int(settings.iterations), int(settings.checkpoints))
    check_memory(
        algorithm,
        int(settings.seeds),
        problem.n_agents,
        problem.n_features,
        2 * network.n_edges,
        len(steps),
        settings.backend,
    )
    ctx, moments, L_mean, fixed, report, w_star, tail_window = prepare(
        problem, network, algorithm, sampling, settings, channel
    )
    w_ref = fixed.w
    T, B, N, q = int(settings.iterations), int(settings.seeds), problem.n_agents, problem.n_features
    if source is None:
        if ctx.tables is None:
            raise DgtdInputError(
                f"{problem.name} has no model to draw samples from; pass its simulator or data as the source"
            )
        source = ModelSource(problem, network, sampling, ctx.tables, settings.seed, range(B), settings.backend)
    if checkpoint_every > 0 and not getattr(source, "resumable", True):
        raise DgtdInputError(
            "this run's samples come from a simulator whose state cannot be saved, so it cannot be "
            "resumed from a checkpoint: leave out --checkpoint-every (checkpoint_every)"
        )
    from dgtd.backends import mpi

    mpi.check_supported(algorithm, ctx.channel, N, settings.backend, settings.asynchronous)
    if settings.backend == "jax":
        from dgtd.backends import jax as on_jax

        on_jax.check_supported(ctx.channel)
    asynchronous = settings.asynchronous and mpi.spreads(algorithm)
    if mpi.spreads(algorithm):  # ranks of an mpiexec job: the agents spread over them (`dgtd.backends.mpi`)
        kernel = mpi.kernel(ctx, settings.backend, settings.staleness if asynchronous else False)
        if asynchronous:
            mpi.message_ages(restore=mpi.NO_AGES if resume is None else resume["message_ages"])
        source = mpi.local_source(ctx, source)  # each rank draws the numbers of its agents and their neighbours only
        layout = mpi.Ranks(ctx)  # ... and holds their rows only
    else:
        kernel = kernel_for(settings.backend, algorithm, ctx.channel)
        layout = Whole(ctx)
    algorithm = ctx.algorithm
    state = algorithm.init(B, N if layout.agents is None else len(layout.agents), q)
    channel = layout.init_channel(ctx.channel, B, settings.seed)
    if problem.w0 is not None:  # the task's prescribed start (Baird's); every state names the value weights w
        state = state._replace(w=np.broadcast_to(problem.w0, state.w.shape).copy())
    n_est = algorithm.estimate(state).shape[1]  # the agents' estimates held here, or 1 for a centralised learner
    n_all = n_est if layout.agents is None else N  # ... and of the whole run
    w_ref_held = layout.rows(w_ref)
    # Kernels keep one running sum of w_k; the tail average is its difference from a copy taken at tail_start (a
    # block boundary), so no kernel reads or writes a second sum.
    sums = {"all": np.zeros((B, n_est, q))}
    tail_base = None
    C = len(steps)
    names = (
        "error_last",
        "error_avg",
        "error_tail",
        "value_error_last",
        "value_error_avg",
        "value_error_tail",
        "consensus",
        "mspbe_last",
        "mspbe_avg",
        "rmspbe_last",
        "rmspbe_avg",
        "rmspbe_tail",
    )
    metrics = {m: np.zeros((C, B)) for m in names}
    counts = {m: np.zeros((C, B)) for m in COUNTS}
    err_last, err_avg = np.zeros((C, B, n_est)), np.zeros((C, B, n_est))
    keep_trace = B * n_all * q * C <= TRACE_MAX
    w_trace = np.zeros((C, B, n_all, q)) if keep_trace and layout.root else None  # (rank 0 gathers it)
    # The running sum at every checkpoint, for the tail average at each checkpoint (`tail_at`): up to 160 MB (it is
    # not saved with the results, unlike the trace), else the tail metrics are NaN
    sum_trace = np.zeros((C, B, n_est, q)) if B * n_all * q * C <= SUM_TRACE_MAX else None
    # the channel's counts, frozen for a seed once it diverges (a stopped seed sends nothing)
    messages, bits, diverged_at = np.zeros(B), np.zeros(B), np.full(B, -1, dtype=np.int64)
    per_arc = np.zeros((B, 0))  # how often each arc delivered, where the channel counts it (`Imperfect`)
    w0_norm = 0.0 if problem.w0 is None else float(np.abs(problem.w0).max())
    limit = DIVERGENCE_FACTOR * max(1.0, float(np.abs(w_star).max()), w0_norm)
    k, c, seconds_before = 0, 0, 0.0
    if resume is None:
        source.start()
    else:
        from dgtd.run.checkpoint import assemble

        trajectories = getattr(source, "state_agents", None)  # a rank's Markov chains
        resume = assemble(resume, N, ctx.arcs.n_arcs, layout.agents, layout.arc_ids, trajectories)
        k, c, seconds_before = int(resume["k"]), int(resume["c"]), float(resume["seconds"])
        state = state._make(np.array(resume["state"][f]) for f in state._fields)
        sums = {name: np.array(v) for name, v in resume["sums"].items()}
        tail_base = None if resume.get("tail_base") is None else np.array(resume["tail_base"])
        metrics = {name: np.array(v) for name, v in resume["metrics"].items()}
        err_last, err_avg = np.array(resume["agent_error_last"]), np.array(resume["agent_error_avg"])
        w_trace = None if resume["w_trace"] is None or not layout.root else np.array(resume["w_trace"])
        sum_trace = None if resume.get("sum_trace") is None else np.array(resume["sum_trace"])
        messages, bits = np.array(resume["messages"], dtype=np.float64), np.array(resume["bits"], dtype=np.float64)
        saved = resume["channel"]  # the fields of the channel's own state (older checkpoints hold every channel's)
        channel = channel._make(np.array(saved[name]) if name in saved else x for name, x in channel._asdict().items())
        per_arc = np.array(resume.get("per_arc", per_arc), dtype=np.float64)
        diverged_at = np.array(resume.get("diverged_at", diverged_at), dtype=np.int64)
        counts = {name: np.array(v) for name, v in resume.get("counts", counts).items()}
        source.set_state(resume["source"])
    every = int(checkpoint_every)
    # Kernels that draw their own samples (`Draws`) materialise nothing: their blocks are bounded by work (a few
    # seconds between progress updates), not by the memory of a block of samples.
    fused = getattr(kernel, "draws_samples", False) and isinstance(source, ModelSource)
    if fused:  # a rank sets its share's driver up at each block: longer blocks (each rank steps N / R agents)
        block = block_steps(settings.block_size, N, 0, B, budget=(1 << 24) * (16 if mpi.spreads(algorithm) else 1))
    else:
        block = block_steps(settings.block_size, N, network.n_edges, B)
    t_kernel = time.perf_counter()
    # An empty block: the kernel loads or compiles now (not inside the first step, where it would look like a
    # stalled run), and nothing moves. A simulator's agents each observe their own state.
    if isinstance(source, ModelSource):
        kernel(ctx, state, channel, sums["all"], np.zeros(0), source.draws(0) if fused else source.next_block(0))
    else:
        kernel(ctx, state, channel, sums["all"], np.zeros(0), Block.empty(B, N, N, network.n_edges))
    kernel_seconds = time.perf_counter() - t_kernel
    if kernel_ready is not None:
        kernel_ready(kernel_seconds)
    t_loop, cpu_loop = time.perf_counter(), time.process_time()
    while k < T:
        if k == ctx.tail_start and tail_base is None:
            tail_base = sums["all"].copy()
        k1 = min(
            k + block,
            int(steps[c]),
            (k // every + 1) * every if every else T,
            ctx.tail_start if k < ctx.tail_start else T,
        )
        blk = source.draws(k1 - k) if fused else source.next_block(k1 - k)
        alphas = step_sizes(algorithm.schedule, algorithm.alpha0, algorithm.beta, k, k1)
        with np.errstate(over="ignore", invalid="ignore"):  # a diverging seed is detected below, not warned about
            state, channel, w_sum = kernel(ctx, state, channel, sums["all"], alphas, blk)
        sums = {"all": w_sum}
        live = diverged_at < 0
        messages, bits = np.where(live, channel.messages, messages), np.where(live, channel.bits, bits)
        if ctx.channel.holds and channel.per_arc.size:
            per_arc = np.where(live[:, None], channel.per_arc, per_arc if per_arc.size else channel.per_arc)
        if progress is not None:
            progress(k1 - k)
        k = k1
        state, sums = stop_diverged(state, sums, algorithm.estimate(state), limit, diverged_at, k, layout.any)
        if k == steps[c]:
            alive = diverged_at < 0
            w, w_avg = algorithm.estimate(state), sums["all"] / k
            for x in (*metrics.values(), *counts.values()):
                x[c] = np.nan
            err_last[c], err_avg[c] = np.nan, np.nan
            if alive.any():
                wa, wv = w[alive], w_avg[alive]

                def worst(x):  # the worst agent of every live seed, over the ranks where they are spread
                    return layout.max(x.max(-1))

                def value_error(x):
                    return worst(exact.value_error(moments, x, w_ref_held, of=w_ref))

                err_last[c, alive] = exact.relative_error(wa, w_ref_held, of=w_ref)
                err_avg[c, alive] = exact.relative_error(wv, w_ref_held, of=w_ref)
                metrics["error_last"][c, alive] = worst(err_last[c, alive])
                metrics["error_avg"][c, alive] = worst(err_avg[c, alive])
                metrics["value_error_last"][c, alive] = value_error(wa)
                metrics["value_error_avg"][c, alive] = value_error(wv)
                if sum_trace is not None:
                    sum_trace[c] = sums["all"]
                    wt = tail_at(c, steps, sum_trace, settings.tail_fraction)[alive]
                    metrics["error_tail"][c, alive] = worst(exact.relative_error(wt, w_ref_held, of=w_ref))
                    metrics["value_error_tail"][c, alive] = value_error(wt)
                    metrics["rmspbe_tail"][c, alive] = worst(exact.rmspbe(moments, wt))
                metrics["consensus"][c, alive] = layout.consensus(wa)
                metrics["mspbe_last"][c, alive] = worst(exact.mspbe(moments, wa))
                metrics["mspbe_avg"][c, alive] = worst(exact.mspbe(moments, wv))
                metrics["rmspbe_last"][c, alive] = worst(exact.rmspbe(moments, wa))
                metrics["rmspbe_avg"][c, alive] = worst(exact.rmspbe(moments, wv))
                counts["samples"][c, alive] = N * k  # one sample per agent per step, for every algorithm
                counts["messages"][c, alive] = messages[alive]
                counts["bits"][c, alive] = bits[alive]
            counts["diverged"][c] = ~alive
            if keep_trace:
                whole = layout.whole(w)  # (a collective where the agents are spread)
                if w_trace is not None:
                    w_trace[c] = whole
            c += 1
            if not alive.any():  # every seed has diverged: nothing left to run
                for x in (*metrics.values(), *counts.values()):
                    x[c:] = np.nan
                counts["diverged"][c:] = 1.0
                err_last[c:], err_avg[c:] = np.nan, np.nan
                if w_trace is not None:
                    w_trace[c:] = np.nan
                break
        checkpoint = every and k % every == 0 and k < T
        ages = mpi.message_ages() if asynchronous and checkpoint else {}  # a collective: every rank, saving or not
        source_state = source.get_state() if checkpoint else None  # the same (a rank's source holds its own agents)
        if checkpoint and on_checkpoint is not None:
            on_checkpoint(
                snapshot(
                    k,
                    c,
                    state,
                    sums,
                    metrics,
                    err_last,
                    err_avg,
                    w_trace,
                    source_state,
                    seconds_before + time.perf_counter() - t_start,
                    extra={
                        **layout.shard(),  # the agents and arcs whose rows this snapshot holds (a rank's)
                        "messages": messages,
                        "bits": bits,
                        "channel": reported(channel, layout)._asdict(),
                        "per_arc": layout.reported(per_arc) if per_arc.size else per_arc,
                        "diverged_at": diverged_at,
                        "counts": counts,
                        **({} if tail_base is None else {"tail_base": tail_base}),
                        **({} if sum_trace is None else {"sum_trace": sum_trace}),
                        **({"message_ages": {n: ages[n] for n in ("counts", "transit")}} if ages else {}),
                    },
                )
            )
    loop_seconds, loop_cpu = time.perf_counter() - t_loop, time.process_time() - cpu_loop
    # Every agent's rows on rank 0 where the agents are spread (its own on the others: their results are not written)
    state = state._make(layout.whole(x) for x in state)
    w_sum, tail_sum = layout.whole(sums["all"]), None if tail_base is None else layout.whole(tail_base)
    err_last, err_avg = layout.whole(err_last, axis=2), layout.whole(err_avg, axis=2)
    if ctx.channel.holds:  # a channel whose receivers hold copies counts each arc's deliveries (a collective)
        per_arc = layout.whole_arcs(per_arc, ctx.arcs.n_arcs)
    if layout.root:
        report = {**fixed.report, **report, **algorithm.diagnostics(state, moments, L_mean)}
    return RunResult(
        steps=steps,
        metrics=metrics,
        agent_error_last=err_last,
        agent_error_avg=err_avg,
        w_trace=w_trace,
        w_last=algorithm.estimate(state),
        w_avg=w_sum / T,
        w_tail=(w_sum - (np.nan if tail_sum is None else tail_sum)) / tail_window,
        tail_window=tail_window,
        w_star=w_star,
        fixed=fixed,
        final_state=state._asdict(),
        report=report,
        seconds=seconds_before + time.perf_counter() - t_start,
        info={
            "d": moments.d,
            "moments": moments,
            "mspbe_w_star": float(exact.mspbe(moments, w_star)),
            "diverged_at": diverged_at,
            "samples_per_step": N,
            "messages": messages,
            "bits": bits,
            "counts": counts,
            **(per_agent_counts(ctx, per_arc) if layout.root else {}),
            # how far DGTD's regularised saddle point (rho > 0) is from w* (|.|_inf relative); lost messages move the
            # fixed point too, which the results report as w_fixed
            "regularisation_shift": float(exact.relative_error(w_ref, w_star).max())
            if getattr(algorithm, "rho", 0.0)
            else 0.0,
            **({"message_ages": mpi.message_ages()} if asynchronous else {}),
            "loop_seconds": loop_seconds,  # the steps and their metrics (not the results gathered after them)
            "loop_cpu_seconds": loop_cpu,
            "kernel_seconds": kernel_seconds,
        },
    )


def per_agent_counts(ctx, per_arc: np.ndarray) -> dict:
    """{"per_agent": {"messages", "bits"}}: what each agent sent that arrived (B, N), where the channel counts each
    arc's deliveries (`dgtd.channels.Imperfect`), else nothing."""
    if per_arc.size == 0:
        return {}
    M, q = len(ctx.algorithm.messages), ctx.problem.n_features
    sent = np.zeros((per_arc.shape[0], ctx.arcs.n_agents))
    np.add.at(sent, (slice(None), ctx.arcs.src), per_arc)
    return {"per_agent": {"messages": sent * M, "bits": sent * M * ctx.channel.vector_bits(q)}}


def stop_diverged(state, sums, w: np.ndarray, limit: float, diverged_at: np.ndarray, k: int, any_=None):
    """Mark seeds whose estimate is not finite or exceeds ``limit`` as diverged at step k (in place in
    ``diverged_at``) and stop them: their state and sums become NaN, which every kernel carries along. ``any_``:
    whether any rank found a seed so (`dgtd.backends.mpi.Ranks.any`), where the agents are spread."""
    bad = ~np.all(np.isfinite(w), axis=(1, 2)) | (np.nan_to_num(np.abs(w), nan=np.inf).max(axis=(1, 2)) > limit)
    for x in state:
        bad |= ~np.all(np.isfinite(x.reshape(x.shape[0], -1)), axis=1)
    bad = bad if any_ is None else any_(bad)
    new = bad & (diverged_at < 0)
    if not new.any():
        return state, sums
    diverged_at[new] = k
    state = type(state)(*(np.where(new[:, None, None], np.nan, x) for x in state))
    sums = {key: np.where(new[:, None, None], np.nan, v) for key, v in sums.items()}
    return state, sums


def block_steps(block_size: int, n_agents: int, n_edges: int, n_seeds: int, budget: int = 1 << 21) -> int:
    """Steps per block: at most ``block_size``, and few enough that a block's samples stay near ``budget``
    numbers (tens of MB), whatever N and |E|. Results do not depend on it."""
    per_step = n_seeds * (4 * n_agents + n_edges)
    return int(max(1, min(int(block_size), budget // max(per_step, 1))))


def tail_at(c: int, steps: np.ndarray, sum_trace: np.ndarray, fraction: float) -> np.ndarray:
    """The tail average at checkpoint c: the mean of w_j over the steps since the latest checkpoint at or before
    (1 - fraction) k_c (all of them when there is none), from the running sums recorded at the checkpoints; it
    approximates the final `RunResult.w_tail` at the last checkpoint, where the window is (1 - fraction) T exactly."""
    k = steps[c]
    before = np.flatnonzero(steps[:c] <= (1.0 - fraction) * k)
    if before.size == 0:
        return sum_trace[c] / k
    j = before[-1]
    return (sum_trace[c] - sum_trace[j]) / (k - steps[j])


def snapshot(k, c, state, sums, metrics, err_last, err_avg, w_trace, source_state, seconds, extra=None) -> dict:
    """The loop's whole state after step k, as copies: what `run` needs to continue (its ``resume``).
    ``extra``: more arrays to restore (messages sent so far, divergence steps)."""
    return {
        **{
            name: (np.array(v) if not isinstance(v, dict) else {n: np.array(x) for n, x in v.items()})
            for name, v in (extra or {}).items()
        },
        "k": int(k),
        "c": int(c),
        "seconds": float(seconds),
        "state": {f: np.array(x) for f, x in state._asdict().items()},
        "sums": {name: v.copy() for name, v in sums.items()},
        "metrics": {name: v.copy() for name, v in metrics.items()},
        "agent_error_last": err_last.copy(),
        "agent_error_avg": err_avg.copy(),
        "w_trace": None if w_trace is None else w_trace.copy(),
        "source": source_state,
    }


def kernel_for(backend: str, algorithm, channel=None):
    """The block kernel of ``algorithm`` over ``channel`` on ``backend`` (`dgtd.backends.reference.run_block`
    contract): the compiled driver where the algorithm has a compiled step and the channel a compiled twin; else the
    reference, with a one-line notice."""
    from dgtd.backends.reference import run_block

    if backend == "numpy":
        return run_block
    if backend == "jax":
        from dgtd.backends import jax as on_jax

        return on_jax.run_block
    from dgtd.backends.compiled import fallback
    from dgtd.backends.compiled import run_block as compiled

    if reason := fallback(algorithm, channel):
        import warnings

        warnings.warn(reason, stacklevel=3)
        return run_block
    return compiled


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
        network,
        algorithm,
        sampling,
        RunSettings(iterations=iterations, seeds=seeds, seed=seed, backend=backend, **settings),
        channel=channel,
    )
