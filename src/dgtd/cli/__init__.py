"""The `dgtd` command line: run, solve, scenarios, compare. Bad input prints one line and exits with code 2."""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

import click
import numpy as np

from dgtd.cli.options import (
    ALGORITHM_OPTIONS,
    LINK_OPTIONS,
    given_flags,
    output_options,
    problem_line,
    resume_folder,
    run_options,
    sweep_options,
)
from dgtd.config import CHOICES, Output
from dgtd.errors import DgtdInputError, UserCodeError
from dgtd.run import runtime

DEBUG = {"on": False}  # set by `dgtd --debug`: the traceback of an error raised in a user's own code is printed


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="dgtd")
@click.option(
    "--debug",
    is_flag=True,
    default=False,
    help="Where your own code (env, policy, features) raised an error, print its traceback too.",
)
def cli(debug):
    """dgtd: distributed policy evaluation with the primal-dual distributed GTD method (Algorithm 1)."""
    DEBUG["on"] = debug


def _is_experiment_file(arg: str | None) -> bool:
    return arg is not None and arg.endswith(".toml")


@cli.command()
@click.argument("scenario", required=False, metavar="SCENARIO|EXPERIMENT.toml")
@run_options()
@output_options()
@click.option(
    "--resume",
    "resume_dir",
    type=click.Path(file_okay=False),
    default=None,
    help="Continue the run saved in DIR from its last checkpoint; ends with the numbers of an uninterrupted run. "
    "With a larger -T, a finished run that ran with --checkpoint-every goes on from its end to the numbers of a run "
    "of that length.",
)
@click.option(
    "--ranks",
    type=int,
    default=None,
    help="Spread the agents over R processes: starts the mpi extra's mpiexec -n R (docs/distributed.md).",
)
@click.option(
    "--hosts",
    type=str,
    default=None,
    help="With --ranks: an MPICH host file (host or host:slots a line); every host is checked before any starts.",
)
@click.pass_context
def run(ctx, scenario, resume_dir, ranks, hosts, **_):
    """Run an algorithm on a named SCENARIO (e.g. paper-example-1), on --problem FILE.npz, or as an EXPERIMENT.toml.

    Flags override the experiment file's fields; the results directory gets config.toml, the fully
    resolved experiment, so that `dgtd run DIR/config.toml` reproduces the run.

    \b
    Defaults: without step-size options DGTD runs with alpha_k = 10/sqrt(k+1000)
    and kappa = 3, the fastest found on the benchmark tasks; paper-example-1 and -2
    keep the paper's own settings, and the random-MDP tasks a smaller alpha0 for
    their larger features. On --problem, --env or --data the first step of any
    method comes from its mean dynamics (the header says which and why).

    \b
    What it reports for every agent i, against the exact solution w*:
      weight error  |w_i - w*|_inf / |w*|_inf, the largest weight error;
      value error   |Phi (w_i - w*)|_d / |Phi w*|_d, the RMS error of the values
                    weighted by d, the stationary distribution of the sampled
                    states (RMSVE), relative to their size: the error that
                    matters when some weight directions barely change values;
      MSPBE, RMSPBE the projected Bellman error, and its root; and the consensus
                    error;
    each for the last iterate, the average over the whole run, and the tail
    average (the last --tail-fraction of the run, which forgets the start):
    metrics.csv per seed, bands.csv the median and 90 % band over seeds.
    """
    from dgtd.cli.job import CONFIG, prepare
    from dgtd.experiments import experiment_from

    if ranks is not None or hosts is not None:
        from dgtd.cli.launch import launch

        ctx.exit(launch(ranks, hosts, ARGV))
    flags = given_flags(ctx, exclude=("scenario", "resume_dir", "ranks", "hosts"))
    file = scenario if _is_experiment_file(scenario) else None
    if scenario is not None and file is None:
        flags["scenario"] = scenario
    if resume_dir is not None:
        resume_folder(resume_dir, flags.get("out"), "run", "dgtd run SCENARIO")
        flags.update(out=resume_dir, resume=True)
        if file is None and not PROBLEM_FLAGS & set(flags):
            file = str(Path(resume_dir) / CONFIG)
    if file is None and not PROBLEM_FLAGS & set(flags):
        raise DgtdInputError(
            "name a scenario (dgtd scenarios lists them), give --problem FILE.npz, --env "
            "module:make_env, --data FILE, or an EXPERIMENT.toml"
        )
    import time

    t_start = time.perf_counter()
    job = prepare(experiment_from(file, flags))
    try:
        _run_job(job, t_start)
    finally:
        job.release()


def _run_job(job, t_start: float) -> None:
    """`dgtd run`'s work once its directory is its own: the run, its files and its report."""
    import time

    from dgtd.cli.job import CONFIG

    t_prepared = time.perf_counter()
    if job.finished:
        click.echo(f"{job.out}: the run is already finished (summary.json); nothing to resume")
        return
    click.echo(run_header(job))
    if job.snapshot is not None:
        if job.extends is not None:
            T = job.settings.iterations
            click.echo(f"extending the finished run in {job.out} from {job.extends:,} to {T:,} steps")
        else:
            click.echo(f"resuming {job.out} at iteration {job.snapshot['k']:,}")
    result = job.run()
    if not runtime.writes():  # one process writes the results and reports them
        if result.rows is not None:  # its agents' rows, and its part of what the table combines
            job.save(result)
            final_table(result)
            report_notes(job, result)
        return
    t_ran = time.perf_counter()
    if job.config.output.plots:
        print("writing the results, then drawing the figures ...", file=sys.stderr, flush=True)
    from dgtd.run.results import NotWritten

    try:
        names = job.save(result)
    except NotWritten:
        click.echo(final_table(result))  # the numbers are in memory: the user sees them whatever the disk kept
        raise
    t_saved = time.perf_counter()
    click.echo(final_table(result))
    report_notes(job, result)
    kernels = result.info.get("kernel_seconds", 0.0)
    click.echo(
        f"wrote {job.out}/{CONFIG}, {', '.join(names)} ({t_saved - t_start:.1f} s in all: setup "
        f"{t_prepared - t_start:.1f} s, kernels {kernels:.1f} s, run {t_ran - t_prepared - kernels:.1f} s, "
        f"results and figures {t_saved - t_ran:.1f} s)"
    )


def run_header(job) -> str:
    """The lines a run starts with: its problem and links, its algorithm and settings, where its samples come from,
    and the first step chosen from the problem where it was."""
    from dgtd.config import scenario_of, steps_note

    lines = []
    problem, network, algorithm, samp, settings = job.problem, job.network, job.algorithm, job.sampling, job.settings
    links = network.describe()
    if job.resolved.problem.scenario is not None and scenario_of(job.resolved).source is not None:
        links = "set by the scenario's own simulation (see its report)"
    channel = job.channel
    if channel.name != "perfect":  # lost, late, asleep or compressed messages
        links += f"; {channel.describe()}"
    lines.append(problem_line(problem, links))
    if job.resolved.problem.data is not None:  # the source's own samples: the run's Sampling is not used
        samples = "the recording's samples"
    elif job.resolved.problem.env is not None:
        samples = "the simulator's samples"
    else:
        samples = f"{samp.mode} sampling, {'shared' if samp.shared else 'independent'} states"
    lines.append(
        f"{algorithm.describe()}; {settings.iterations:,} iterations x {settings.seeds} seed(s), {samples}, "
        f"{settings.backend} backend"
    )
    if job.resolved.problem.env is not None or job.resolved.problem.data is not None:
        lines.append(scenario_of(job.resolved).description)
    if settings.backend == "jax":
        from dgtd.backends import jax as on_jax

        if on_jax.available() and on_jax.on_cpu():
            lines.append(on_jax.ON_CPU)
    note = steps_note(job.config, problem, network, algorithm)  # the step chosen and why, or a growing mode
    if note:
        lines.append(note)
    return "\n".join(lines)


FARTHER = 1.5  # a tail average this many times as far from the reference as the start: not converged


def not_converged(job, result) -> str:
    """A warning where the worst agent's tail-averaged estimate ends `FARTHER` times as far from the run's reference
    as its start (w0, or 0: 100 %) or more without having diverged, with what to change on compressed links; else
    ""."""
    from dgtd.problems import exact
    from dgtd.run.results import reference

    ref = reference(result)
    w0 = job.problem.w0 if job.problem.w0 is not None else np.zeros(ref.shape[-1])
    start = float(exact.relative_error(w0, ref, of=ref).max())
    worst = worst_error(result, result.w_tail)
    if worst <= FARTHER * max(start, 1.0):  # (a run that barely moved ends near its start: no word)
        return ""
    channel = job.channel
    hint = ""
    if getattr(channel, "bits", 64) < 64 and not getattr(channel, "error_feedback", False):
        hint = (
            f"; messages rounded to {channel.bits} bit(s) without error feedback carry noise as large as themselves: "
            "add --error-feedback, or give more --bits"
        )
    return (
        f"warning: the run did not converge: the worst agent's tail-averaged estimate ended {worst:.0%} from the "
        f"reference, farther than it started ({start:.0%}){hint or '; lower the steps (--alpha0, or raise --beta)'}"
    )


def worst_error(result, w) -> float:
    """The worst agent's relative distance of ``w`` (the run's last, averaged or tail-averaged estimates) from the
    run's reference, over the seeds and the ranks (0 where none is finite)."""
    from dgtd.problems import exact
    from dgtd.run.results import held_reference, over_agents, reference

    error = exact.relative_error(w, held_reference(result), of=reference(result))
    largest = float(np.max(np.where(np.isnan(error), 0.0, error), initial=0.0))
    worst, any_finite = over_agents(result, np.array([[largest], [float(np.isfinite(error).any())]]))
    return float(worst) if any_finite else 0.0


LAGS = 3.0  # a tail average this many times as far from the reference as the last iterate (and 1 % or more): said


def tail_lags(result) -> str:
    """A note where the tail-averaged estimate, the output to read, lags the last iterate by `LAGS` times or more
    (and is 1 % or more from the reference): the tail's first steps were still far, so the run was too short for its
    steps (at 1 000 agents on a sparse random graph, 10^5 steps: 0.36 % last, 45.8 % tail-averaged); else ""."""
    last, tail = worst_error(result, result.w_last), worst_error(result, result.w_tail)
    if not (np.isfinite(last) and tail >= max(LAGS * last, 0.01)):
        return ""
    return (
        f"note: the tail-averaged estimate (w_tail, {tail:.2%} from the reference) lags the last iterate (w_last, "
        f"{last:.2%}): the run's tail began before its estimates settled; give more -T (or a smaller --tail-fraction), "
        "or read w_last in summary.json"
    )


def report_notes(job, result) -> None:
    """What the run's end says beside its table: boxes that grew, iterates pinned to them, the scenario's report."""
    from dgtd.run.results import pinned_to_boxes

    for name, box in result.report.get("boxes_grown", {}).items():
        click.echo(
            f"note: the {name} box grew from {box['lemma']:.4g} (Lemma 2's bound) to {box['used']:.4g} "
            f"(box_scale x |{name}*|_inf), so that it contains the saddle point",
            err=True,
        )
    far = not_converged(job, result)
    if far:
        click.echo(far, err=True)
    lags = "" if far else tail_lags(result)
    if lags:
        click.echo(lags, err=True)
    pinned = pinned_to_boxes(result)
    if pinned:
        click.echo(
            "warning: at the end of the run "
            + ", ".join(f"{frac:.0%} of {name}" for name, frac in pinned.items())
            + " sit on the projection boxes: the step sizes are likely too large (lower --alpha0 or raise "
            "--beta), or the boxes too small",
            err=True,
        )
    if job.report_text:
        click.echo(job.report_text)


PROBLEM_FLAGS = {"scenario", "problem_file", "env_make", "data"}


def _vec(x, n=4) -> str:
    s = ", ".join(f"{v:.4g}" for v in x[:n])
    return f"({s}{', ...' if len(x) > n else ''})"


TABLE_AGENTS = 20  # agents the final table shows at most: the first half of them, then the worst


def _shown_agents(ids: np.ndarray, tail_error: np.ndarray, n_agents: int) -> np.ndarray:
    """Of the agents ``ids`` (with their tail-averaged errors, seed 0) those the table shows: every agent where there
    are at most `TABLE_AGENTS`; else the first TABLE_AGENTS / 2 and the worst as many of the others by their
    tail-averaged error (ties: the lower id), in that order. Applied to a rank's agents, then to what every rank
    picked, it picks the same."""
    if n_agents <= TABLE_AGENTS:
        return np.sort(ids)
    half = TABLE_AGENTS // 2
    first = np.sort(ids[ids < half])
    rest = np.flatnonzero(ids >= half)
    order = rest[np.lexsort((ids[rest], -tail_error[rest]))][: TABLE_AGENTS - half]
    return np.concatenate([first, ids[order]])


def _table_rows(result, e_last, e_avg, e_tail) -> list | None:
    """(agent, w_last, w_avg, its three errors) of the agents the table shows (`_shown_agents`, seed 0), in its
    order: picked among this process's rows, and where the rows stay on their ranks, among every rank's picks on
    rank 0 (None on the others)."""
    from dgtd.run.results import n_agents

    ids = np.arange(result.w_last.shape[1]) if result.rows is None else np.asarray(result.rows.agents)
    N = n_agents(result)
    at = {int(i): k for k, i in enumerate(ids)}
    picked = [
        (int(i), result.w_last[0, at[i]], result.w_avg[0, at[i]], e_last[0, at[i]], e_avg[0, at[i]], e_tail[0, at[i]])
        for i in _shown_agents(ids, e_tail[0], N)
    ]
    every = [picked] if result.rows is None else result.rows.collect(picked)
    if every is None:
        return None
    rows = {r[0]: r for part in every for r in part}
    return [rows[i] for i in _shown_agents(np.array(list(rows)), np.array([r[5] for r in rows.values()]), N)]


def _agent_rows(result, e_last, e_avg, e_tail) -> list[str] | None:
    """The table's header and its rows of the agents shown (`_table_rows`), seed 0, the columns lined up however
    long a vector; where some are left out, which and where they are. None on a rank that does not write."""
    from dgtd.run.results import n_agents

    shown = _table_rows(result, e_last, e_avg, e_tail)
    if shown is None:
        return None
    N = n_agents(result)
    last, avg = {r[0]: _vec(r[1]) for r in shown}, {r[0]: _vec(r[2]) for r in shown}
    width = max(34, *(len(v) + 2 for v in [*last.values(), *avg.values()]))
    rows = [
        f"{'agent':>5}  {'w_last (seed 0)':<{width}}{'err':>8}  {'w_avg (seed 0)':<{width}}{'err':>8}  "
        f"{'w_tail err':>10}"
    ]
    for k, (i, _, _, err_last, err_avg, err_tail) in enumerate(shown):
        if k == TABLE_AGENTS // 2 and len(shown) < N:
            rows.append(f"{'...':>5}  the worst {len(shown) - k} by their tail-averaged error:")
        rows.append(
            f"{i + 1:>5}  {last[i]:<{width}}{err_last:>8.2%}  {avg[i]:<{width}}{err_avg:>8.2%}  {err_tail:>10.2%}"
        )
    if len(shown) < N:
        rows.append(f"{'':>5}  ({N - len(shown):,} agents more: every agent's rows in summary.json or agents.npz)")
    return rows


def final_table(result) -> str:
    """Every agent's last and averaged w beside w* (seed 0), then the worst errors over seeds."""
    from dgtd.problems import exact
    from dgtd.run.results import consensus_of, held_reference, over_agents, reference

    ref, held = reference(result), held_reference(result)
    e_last = exact.relative_error(result.w_last, held, of=ref)
    e_avg = exact.relative_error(result.w_avg, held, of=ref)
    e_tail = exact.relative_error(result.w_tail, held, of=ref)
    cons = consensus_of(result, result.w_last)
    agent_rows = _agent_rows(result, e_last, e_avg, e_tail)  # (collectives first, where the rows are spread)
    moments = result.info.get("moments")
    v = {
        k: over_agents(result, exact.value_error(moments, W, held, of=ref)).max()
        for k, W in (("last", result.w_last), ("averaged", result.w_avg), ("tail-averaged", result.w_tail))
    } if moments is not None else None  # fmt: skip
    worst = [over_agents(result, e).max() for e in (e_last, e_avg, e_tail)]
    if agent_rows is None:  # a rank that does not write: its part is done
        return ""
    shift = result.info.get("regularisation_shift", 0.0)
    moved = not shift and not np.array_equal(ref[0], result.w_star)  # lost messages move the fixed point
    rows = [
        f"w* = {_vec(result.w_star, 8)}   (relative errors are |w_i - w*|_inf / |w*|_inf)"
        if not shift
        else f"w* = {_vec(result.w_star, 8)}; with rho > 0 the errors are against each agent's w of the regularised "
        f"saddle point, {shift:.3%} of |w*|_inf away from w*",
    ]
    if moved:
        rows[0] = (
            f"w* = {_vec(result.w_star, 8)}; with the messages lost, the run converges to w_fixed = {_vec(ref[0], 8)} "
            f"(each agent's reward weighted as its links let it be heard: docs/links.md), and the errors are against it"
        )
    rows += agent_rows
    rows.append(f"consensus error sum_i |w_i - mean w|^2 (last, seed 0): {cons[0]:.3g}")
    if moments is not None and not moments.model:
        est = moments.problem.summary()
        rows.insert(
            0,
            f"w* is estimated (no model): LSTD with ridge {est['ridge']:.2g} on {est['transitions']:,} "
            f"transitions (along trajectories) in {est['groups']} independent groups; its "
            "standard error is "
            f"{est['value_stderr_relative']:.2%} of |Phi w*|_d in values ({est['w_star_stderr_relative']:.2%}"
            " of |w*|_inf in weights)"
            + (
                f"; a centralised TD(0) run on {est['td_check_transitions']:,} of them ends "
                f"{est['td_check_value_gap']:.2%} from it"
                if "td_check_value_gap" in est
                else ""
            ),
        )
    if v is not None:
        rows.append(
            "value error |Phi (w_i - w*)|_d / |Phi w*|_d (d: the sampled states' distribution), worst agent "
            "over seeds: " + ", ".join(f"{k} {x:.2%}" for k, x in v.items())
        )
    if result.w_last.shape[0] > 1:
        rows.append(
            f"over {result.w_last.shape[0]} seeds, worst agent: last {worst[0]:.2%}, averaged {worst[1]:.2%}, "
            f"tail-averaged {worst[2]:.2%}; consensus error max {cons.max():.3g}"
        )
    div = np.asarray(result.info.get("diverged_at", []))
    if np.any(div >= 0):  # stopped seeds: their estimates are NaN from then on
        rows.append(
            f"DIVERGED: seed(s) {np.flatnonzero(div >= 0).tolist()} stopped at step(s) {div[div >= 0].tolist()} "
            "(estimates beyond 1e6 x the scale of w*, or not finite)"
            + (
                "; without a model there are no projection boxes: lower --alpha0 (below sqrt(beta) / "
                "lambda_max of the graph's Laplacian is safe)"
                if moments is not None and not moments.model
                else ""
            )
        )
    return "\n".join(rows)


@cli.command()
@click.argument("scenario", required=False)
@run_options("algorithm", *ALGORITHM_OPTIONS, "problem_file", "graph", "edge_prob", *LINK_OPTIONS, "restarts")
@click.pass_context
def solve(ctx, scenario, problem_file, **_):
    """Print the exact solution of a problem as JSON: w*, d, the values, and the fixed point of its algorithm (DGTD's:
    the saddle point theta*, v* = 0, mu*, its KKT residuals and projection boxes), over the network and its links
    (--loss: where each method converges when messages are lost)."""
    from dgtd.channels import Arcs
    from dgtd.config import resolve, unflat
    from dgtd.experiments import Experiment, override
    from dgtd.problems import exact
    from dgtd.run.loop import mean_mixing
    from dgtd.run.results import plain, problem_fields

    if scenario is None and problem_file is None:
        raise DgtdInputError("name a scenario (dgtd scenarios lists them) or give --problem FILE.npz")
    flags = given_flags(ctx, exclude=("scenario", "problem_file"))
    config = override(Experiment(unflat({"scenario": scenario, "problem_file": problem_file})), flags).config
    r = resolve(config)
    problem, network, algorithm, channel = r.problem, r.network, r.algorithm, r.channel
    m = exact.Moments(problem)
    L = mean_mixing(network, channel, Arcs.of(network.base.edges, network.n_nodes), algorithm)
    w = exact.w_star(m)
    fixed = algorithm.fixed_point(m, L, w)
    _, prepared = algorithm.prepare(m, network, fixed)
    out = {
        **problem_fields(problem),
        "w_star": w.tolist(),
        "algorithm": algorithm.name,
        "w_fixed": fixed.w.tolist(),
        # how far its fixed point is from w* (d-weighted value error), and with a channel that loses messages more
        # one way than the other, the weight of each agent's reward in it (`exact.weighted_w_star`)
        "w_fixed_value_distance": float(exact.value_error(m, fixed.w, w).max()),
        "channel": channel.describe(),
        **({} if exact.is_symmetric(L) else {"agent_weights": exact.agent_weights(L).tolist()}),
        **plain(fixed.report),
        **plain(prepared),
        "w_star_per_agent_reward": exact.fixed_point(m, m.b).tolist(),
        "stationary_distribution": m.d.tolist(),
        "mspbe_w_star": float(exact.mspbe(m, w)),
        "value_function": exact.value_function(m).tolist(),
        "approximate_values": (problem.Phi @ w).tolist(),
        "mean_laplacian": L.tolist(),
        "config": {k: v for k, v in dataclasses.asdict(algorithm).items() if v is not None},
    }
    click.echo(json.dumps(out, indent=2))


@cli.command()
@click.option(
    "--cases", default="A,B,C,D,E", show_default=True, help="Which configurations (see dgtd.cli.bench.CASES)."
)
@click.option(
    "--algorithm",
    "algorithms",
    default="dgtd",
    show_default=True,
    help="Algorithms to measure: names separated by commas, or all.",
)
@click.option("--backend", "backends", default="numba,numpy", show_default=True, help="Backends to measure.")
@click.option("--repeats", type=int, default=3, show_default=True, help="Runs per measurement; the median is reported.")
@click.option(
    "--scaling/--no-scaling",
    default=False,
    show_default=True,
    help="Also the scaling table: one seed, N from 16 to 16 384, idle and beside a busy process.",
)
@click.option("--out", type=click.Path(file_okay=False), default="bench", show_default=True)
def bench(cases, algorithms, backends, repeats, scaling, out):
    """Measure agent-steps per second on the standard configurations; writes JSON and a Markdown table."""
    from dgtd.algorithms import ALGORITHMS
    from dgtd.cli.bench import CASES, beside_a_busy_process, markdown, measure
    from dgtd.cli.bench import scaling as scaling_table
    from dgtd.run.results import atomic_write, atomic_write_json

    keys = [k.strip().upper() for k in cases.split(",") if k.strip()]
    unknown = [k for k in keys if k not in CASES]
    if unknown:
        raise DgtdInputError(f"unknown benchmark case(s) {', '.join(unknown)}; choose from {', '.join(CASES)}")
    names = tuple(ALGORITHMS) if algorithms.strip() == "all" else tuple(a.strip() for a in algorithms.split(","))
    bad = [a for a in names if a not in ALGORITHMS]
    if bad:
        raise DgtdInputError(f"unknown algorithm(s) {', '.join(bad)}; choose from {', '.join(ALGORITHMS)}, or all")
    chosen = tuple(b.strip() for b in backends.split(","))
    bad = [b for b in chosen if b not in CHOICES["backend"]]
    if bad:
        raise DgtdInputError(f"unknown backend(s) {', '.join(bad)}; choose from {', '.join(CHOICES['backend'])}")
    if repeats < 1:
        raise DgtdInputError(f"--repeats must be >= 1, got {repeats}")
    report = measure(keys, chosen, repeats, progress=click.echo, algorithms=names)
    if scaling:
        report["scaling"] = {"idle": scaling_table(repeats=repeats, progress=click.echo)}
        click.echo("the same beside a process that keeps one core busy:")
        report["scaling"]["busy"] = beside_a_busy_process(lambda: scaling_table(repeats=repeats, progress=click.echo))
    atomic_write_json(Path(out) / "throughput.json", report)
    atomic_write(Path(out) / "throughput.md", (markdown(report) + "\n").encode())
    click.echo(markdown(report))


@cli.command()
@click.argument("experiment", type=click.Path(dir_okay=False))
@run_options()
@click.option(
    "--out", type=click.Path(file_okay=False), default=None, help="Sweep directory (default: runs/NAME of the file)."
)
@sweep_options()
@click.option("--progress/--no-progress", default=Output.progress, show_default=True)
@click.option(
    "--overwrite/--no-overwrite",
    default=Output.overwrite,
    show_default=True,
    help="Write the sweep into a directory that holds a run's or a comparison's results (refused without it).",
)
@click.pass_context
def sweep(ctx, experiment, **_):
    """Run every point of EXPERIMENT.toml's [grid] as a job; one long table and per-job summaries in OUT.

    Run options given as flags set the base run of every job (grid values win). Rerunning skips finished
    jobs, so an interrupted sweep is continued by running the same command.
    """
    from dgtd.experiments import experiment_from, read_data
    from dgtd.sweep import default_out, run_sweep
    from dgtd.sweep.learning import is_learning

    flags = given_flags(ctx, exclude=("experiment",))
    if Path(experiment).is_file() and is_learning(read_data(experiment)):
        report = _learning_sweep(ctx, experiment, flags)
    else:
        if "resume" in flags:
            flags["sweep.resume"] = flags.pop("resume")
        exp = experiment_from(experiment, flags)
        output = exp.config.output
        out = Path(output.out) if output.out else default_out(experiment)
        report = run_sweep(exp, out, echo=click.echo, progress=output.progress)
    click.echo(
        f"{report['ran']} jobs run, {report['skipped']} skipped (already finished), {len(report['failed'])} failed "
        f"in {report['seconds']:.1f} s" + (f"; table: {report['table']}" if report["table"] else "")
    )
    if report["failed"]:
        for job, message in report["failed"].items():
            click.echo(f"dgtd: job {job} failed: {message}", err=True)
        click.echo("dgtd: run the same command again to retry the failed jobs", err=True)
        sys.exit(1)


def _learning_sweep(ctx, experiment: str, flags: dict) -> dict:
    """`dgtd sweep` of a file with a [learn] table (`dgtd.sweep.learning`): the executor's flags set its [sweep]
    options, the others the base of every job."""
    from dgtd.experiments import SweepOptions, read_data
    from dgtd.sweep import default_out
    from dgtd.sweep.learning import run_learning_sweep

    data = read_data(experiment)
    executor = {k: flags.pop(k) for k in [f.name for f in dataclasses.fields(SweepOptions)] if k in flags}
    if executor:
        data["sweep"] = {**data.get("sweep", {}), **executor}
    out = Path(flags.pop("out")) if flags.get("out") else default_out(experiment)
    overwrite, progress = flags.pop("overwrite", False), flags.pop("progress", ctx.params["progress"])
    return run_learning_sweep(data, experiment, out, flags, overwrite, click.echo, progress)


@cli.command()
@click.argument("directory", type=click.Path(file_okay=False, exists=True))
def plot(directory):
    """Draw the figures of a results DIRECTORY (of `dgtd run` or `dgtd sweep`) from its saved files alone."""
    from dgtd.plots.results import plot_directory

    for path in plot_directory(Path(directory)):
        click.echo(f"wrote {path}")


@cli.command()
def scenarios():
    """List the named scenarios."""
    import shutil
    import textwrap

    from dgtd.scenarios import SCENARIOS

    width = max(shutil.get_terminal_size().columns, 60)
    for name, builder in SCENARIOS.items():  # the builders' first doc paragraphs, whole: listing builds nothing
        about = " ".join((builder.__doc__ or "").strip().split("\n\n")[0].split())
        click.echo(textwrap.fill(about, width, initial_indent=f"{name:<20} ", subsequent_indent=" " * 21))


from dgtd.cli.compare import compare as _compare  # noqa: E402
from dgtd.cli.learn import learn as _learn  # noqa: E402
from dgtd.cli.networked import networked as _networked  # noqa: E402

cli.add_command(_compare)
cli.add_command(_learn)
cli.add_command(_networked)


from dgtd.cli.launch import ARGV  # noqa: E402  (the command line `main` was given, which --ranks passes on)


def _note(message, category, filename, lineno, file=None, line=None) -> None:
    """dgtd's own notices (a `warnings.warn` in dgtd) as one line of the command's; others' as Python shows them."""
    import warnings

    if Path(filename).resolve().is_relative_to(Path(__file__).resolve().parents[1]):
        click.echo(f"dgtd: note: {message}", err=True)
    else:
        click.echo(warnings.formatwarning(message, category, filename, lineno, line).rstrip(), err=True)


def _quiet_ranks() -> None:
    """In an mpiexec job, every rank but 0 prints nothing: the job says each thing once, from rank 0 (a rank's
    watchdog writes its own line directly)."""
    if not runtime.speaks():
        import os

        sys.stdout = sys.stderr = open(os.devnull, "w")  # noqa: SIM115  (for the life of the process)


def _only_run_spreads(argv) -> None:
    """Under mpiexec with more than one rank, `dgtd run` alone spreads its agents over the ranks; any other command
    would run once on every rank and write the same files from each."""
    runtime.check_command(next((a for a in argv if not a.startswith("-")), None))


def main(argv=None) -> None:
    """Entry point: one line and exit code 2 for bad input, never a traceback."""
    import warnings

    DEBUG["on"] = False
    ARGV[:] = sys.argv[1:] if argv is None else list(argv)
    _quiet_ranks()
    try:
        _only_run_spreads(ARGV)
        with warnings.catch_warnings():
            warnings.showwarning = _note
            code = cli.main(args=argv, prog_name="dgtd", standalone_mode=False)
        if isinstance(code, int) and not isinstance(code, bool) and code:  # ctx.exit(code) returns it here
            sys.exit(code)
    except DgtdInputError as e:
        if isinstance(e, UserCodeError) and DEBUG["on"] and e.__cause__ is not None:
            import traceback

            click.echo("".join(traceback.format_exception(e.__cause__)).rstrip(), err=True)
        click.echo(f"dgtd: error: {e}", err=True)
        sys.exit(2)
    except click.exceptions.Exit as e:
        sys.exit(e.exit_code)
    except click.ClickException as e:
        click.echo(f"dgtd: error: {e.format_message()}", err=True)
        sys.exit(e.exit_code)
    except (click.exceptions.Abort, KeyboardInterrupt) as e:
        cause = e.__cause__ if isinstance(e, click.exceptions.Abort) else e  # click wraps Ctrl-C in Abort
        said = cause.args[0] if isinstance(cause, KeyboardInterrupt) and cause.args else None
        line = f"dgtd: {said or 'interrupted; files already written are complete'}"
        click.echo(line, err=True)
        sys.stdout.flush(), sys.stderr.flush()
        runtime.stop_job(130, line)  # the other ranks of an mpiexec job stop too, rather than wait for this one
        sys.exit(130)
    except (MemoryError, OSError) as e:
        click.echo(f"dgtd: error: {e}", err=True)
        sys.exit(2 if isinstance(e, OSError) else 1)


if __name__ == "__main__":
    main()
