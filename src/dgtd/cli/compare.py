"""`dgtd compare`: DGTD beside its baselines on one scenario, on the same sample streams."""

from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path

import click

from dgtd.algorithms import ALGORITHMS
from dgtd.cli.options import ENV_OPTIONS, LINK_OPTIONS, output_options, problem_line, run_options


def _names(text: str | None) -> tuple[str, ...]:
    if text is None:
        return tuple(ALGORITHMS)
    return tuple(a.strip() for a in text.split(",") if a.strip())


@click.command()
@click.argument("scenario", required=False)
@click.option(
    "--algorithms", "-a", type=str, default=None, help=f"Comma-separated: {', '.join(ALGORITHMS)} (default: all)."
)
@click.option(
    "--seeds", type=int, default=5, show_default=True, help="Independent runs per algorithm, the same for all."
)
@click.option(
    "--tune/--no-tune",
    default=False,
    show_default=True,
    help="Pick each algorithm's alpha0 from alpha0 x (1/10, 1/3, 1, 3, 10) on separate seeds first.",
)
@click.option("--tune-seeds", type=int, default=2, show_default=True, help="Seeds per tuning run.")
@click.option(
    "--learn/--no-learn",
    default=False,
    help="Compare agents that learn their policies (dgtd learn) on a learning task or a multi-agent MDP file: "
    "networked with each distributed critic (-a), independent and centralised (a learning task's name implies it).",
)
@output_options(
    "out",
    "progress",
    "plots",
    "overwrite",
    helps={
        "out": "Results directory (default: runs/compare-SCENARIO).",
        "overwrite": "Replace another comparison's results in --out (otherwise refused).",
    },
)
@run_options(
    "iterations",
    "seed",
    "edge_prob",
    "sampling",
    "shared",
    "restarts",
    "backend",
    "checkpoints",
    "problem_file",
    "graph",
    *LINK_OPTIONS,
    *ENV_OPTIONS,
)
def compare(scenario, algorithms, seeds, tune, tune_seeds, learn, out, progress, plots, overwrite, **given):
    """Run several algorithms on SCENARIO (or --problem FILE.npz, --env, --data, as `dgtd run`) with the same
    samples; write metrics.csv, summary.json and plots.

    The run is described, checked and recorded as the `RunConfig` of `dgtd run` (the same fields, defaults and
    checks), plus the algorithms compared and the tuning. Each algorithm's numbers are saved as it finishes: after
    an interrupt, the same command again runs only the algorithms that had not finished."""
    from dgtd.config import PROBLEM_FIELDS, resolve, spec_record, unflat
    from dgtd.errors import DgtdInputError
    from dgtd.experiments import Experiment, absolute_paths, override
    from dgtd.run.compare import CompareSettings, configs_for, finish_directory, prepare_directory, write_compare
    from dgtd.run.owner import Owner
    from dgtd.run.results import NotWritten

    given = {k: v for k, v in given.items() if v is not None}
    from dgtd.problems.team import TASKS
    from dgtd.run.networked import TASKS as NETWORKED

    if scenario in NETWORKED:
        from dgtd.cli.networked import compare_networked_cli

        return compare_networked_cli(scenario, seeds, out, progress, plots, overwrite, given)
    if learn or scenario in TASKS:
        from dgtd.cli.learn import compare_learners

        if tune:  # (it tuned nothing and said nothing)
            raise DgtdInputError(
                "--tune picks the step sizes of methods that evaluate a fixed policy; learners are compared at the "
                "critics' steps given (--alpha0, --beta) and the actors' (--actor-step)"
            )

        return compare_learners(scenario, algorithms, seeds, out, progress, plots, overwrite, given)
    config = override(Experiment(unflat({"scenario": scenario, "seeds": seeds})), given).config
    if all(getattr(config.problem, name) is None for name in PROBLEM_FIELDS):
        raise DgtdInputError(
            "name a scenario (dgtd scenarios lists them), --problem FILE.npz, --env module:make_env or --data FILE"
        )
    r = resolve(absolute_paths(config))
    sc, start = _compared_scenario(config, r)
    cs = CompareSettings(_names(algorithms), r.settings, tune=tune, tune_seeds=tune_seeds)
    configs = configs_for(sc, cs.algorithms)
    out = Path(out) if out else Path("runs") / f"compare-{scenario or r.problem.name}"
    click.echo(_what_runs(r, cs, sc, configs, start, seeds, tune))
    record = {
        **spec_record(r.config),
        "algorithms": list(cs.algorithms),
        "tune": tune,
        "tune_seeds": tune_seeds if tune else None,
    }
    record = json.loads(json.dumps(record))  # as summary.json holds it (lists, not tuples), to compare with it
    with Owner(out, "comparison", overwrite):  # the directory is this comparison's until it ends
        results, used, tables = prepare_directory(out, record, overwrite)
        if results:
            click.echo(
                f"resuming the interrupted comparison in {out}: {', '.join(results)} finished before; running "
                f"{', '.join(a for a in cs.algorithms if a not in results)}"
            )
        _run_each(r, sc, cs, configs, out, record, (results, used, tables), progress)
        try:
            write_compare(out, r.problem, r.network, results, used, tables, record)
        except NotWritten:
            click.echo(table(results, used))  # the numbers are in memory: the user sees them whatever the disk kept
            raise
        finish_directory(out)
        figures = _figures(results, out, f"{r.problem.name}, N={r.problem.n_agents}, {seeds} seeds") if plots else ""
        click.echo(table(results, used))
        click.echo(f"wrote {out}/metrics.csv, bands.csv, agent_errors.npz, summary.json{figures}")


def _compared_scenario(config, r):
    """The scenario the methods are compared on, with each method's steps (from the problem where asked), and the
    first-step rule's start where it applies."""
    from dgtd.config import moments_of, problem_start, scenario_of, steps_from_the_problem, view
    from dgtd.scenarios.user import problem_compare_steps, problem_scenario

    start = problem_start(config) if steps_from_the_problem(view(config)) else None
    sc = scenario_of(r.config)
    if sc is None:
        sc = problem_scenario(r.problem, r.network, r.algorithm, r.sampling, r.settings.iterations, start)
    elif start is not None:  # a simulator or a recording: every method's first step from its estimated mean dynamics
        steps_of, note = problem_compare_steps(moments_of(r.problem), r.network, start, derive=True)
        sc = replace(sc, algorithm=r.algorithm, compare_settings=steps_of, compare_note=note)
    return sc, start


def _what_runs(r, cs, sc, configs, start, seeds, tune) -> str:
    """The lines a comparison starts with: the problem, the methods and their step sizes, and where those come from."""
    from dgtd.algorithms.stepsizes import describe as describe_steps

    samp, settings = r.sampling, r.settings
    lines = [
        f"{problem_line(r.problem, r.network.describe())}; {samp.mode} sampling, "
        f"{'shared' if samp.shared else 'independent'} states",
        f"{', '.join(cs.algorithms)}: {settings.iterations:,} iterations x {seeds} seed(s) each"
        f"{', step sizes tuned first' if tune else ''}",
    ]
    if not tune:
        origin = sc.compare_note if sc.compare_settings else "each method's default, with the run's schedule"
        if start is not None:  # each method's offset is its own: say the whole schedule
            steps = ", ".join(f"{name} {describe_steps(a.schedule, a.alpha0, a.beta)}" for name, a in configs.items())
            lines.append(f"alpha_k: {steps} ({origin}); --tune picks each alpha0 from x (1/10 .. 10) on separate seeds")
        else:
            steps = ", ".join(f"{name} {a.alpha0:.3g}" for name, a in configs.items())
            lines.append(f"alpha0: {steps} ({origin}); --tune picks each from alpha0 x (1/10 .. 10) on separate seeds")
    return "\n".join(lines)


def _run_each(r, sc, cs, configs, out: Path, record: dict, done: tuple, progress: bool) -> None:
    """Every method not finished yet, each saved as it finishes; after Ctrl-C, what finished is written and the
    message says how to run the rest."""
    from tqdm import tqdm

    from dgtd.run.compare import compare as run_compare
    from dgtd.run.compare import save_part, write_compare

    results, used, tables = done
    iterations = r.settings.iterations
    bar = tqdm(
        total=iterations * len(cs.algorithms),
        initial=iterations * len(results),
        unit="it",
        unit_scale=True,
        disable=not progress,
        file=sys.stderr,
        mininterval=0.5,
    )
    try:
        run_compare(
            r.problem,
            r.network,
            r.sampling,
            configs,
            cs,
            progress=lambda name, n: bar.update(n),
            log=bar.write if cs.tune else None,
            source_factory=sc.source,
            done=done,
            on_finished=lambda name, result, alg, table: save_part(out, name, result, alg, table, record),
            kernel_ready=lambda seconds: bar.unpause(),  # the compilation is not in the ETA
            channel=r.channel,
        )
    except KeyboardInterrupt:
        bar.close()
        finished = [name for name in cs.algorithms if name in results]
        if not finished:
            raise
        missing = [name for name in cs.algorithms if name not in results]
        interrupted = {**record, "interrupted": True, "missing": missing}
        write_compare(out, r.problem, r.network, results, used, tables, interrupted)
        raise KeyboardInterrupt(
            f"interrupted: the results of {', '.join(finished)} are written to {out} "
            f"(metrics.csv, agent_errors.npz, summary.json); {', '.join(missing)} did not run "
            f"to the end: run the same command again to run only those"
        ) from None
    finally:
        bar.close()


def _figures(results: dict, out: Path, title: str) -> str:
    """The comparison's figures; returns their names as the closing line lists them."""
    from dgtd.plots.compare import plot_compare, plot_consensus

    plot_compare(results, out / "compare.png", title)
    figures = ", compare.png"
    if plot_consensus(results, out / "consensus.png", title):  # none when only centralised learners ran
        figures += ", consensus.png"
    return figures


def table(results: dict, used: dict) -> str:
    """Final worst-agent errors (median over seeds) and divergence, one line per algorithm: weight errors in the max
    norm, value errors |Phi (w_i - w*)|_d / |Phi w*|_d, and the area under the value error curve (`error_area`: a
    diverged seed counts as one that stopped learning)."""
    import numpy as np

    from dgtd.fields import run_options
    from dgtd.run.compare import error_area

    rows = [
        f"{'algorithm':<14}{'alpha0':>8}{'error last':>12}{'error avg':>12}{'value last':>12}{'value avg':>12}"
        f"{'value tail':>12}{'value area':>12}{'MSPBE last':>12}{'messages':>12}{'bits':>12}  diverged"
    ]
    for name, r in results.items():

        def med(k, r=r):
            return np.nanmedian(r.metrics[k][-1]) if np.isfinite(r.metrics[k][-1]).any() else float("nan")

        div = r.info["diverged_at"]
        d = (
            "no"
            if not np.any(div >= 0)
            else f"{int(np.sum(div >= 0))}/{len(div)} seeds (first at step {int(div[div >= 0].min()):,})"
        )
        rows.append(
            f"{name:<14}{used[name].alpha0:>8.3g}{med('error_last'):>12.3g}{med('error_avg'):>12.3g}"
            f"{med('value_error_last'):>12.3g}{med('value_error_avg'):>12.3g}{med('value_error_tail'):>12.3g}"
            f"{np.median(error_area(r)):>12.3g}"
            f"{med('mspbe_last'):>12.3g}{float(np.max(r.info['messages'])):>12.3g}"
            f"{float(np.max(r.info['bits'])):>12.3g}  {d}"
        )
    repeat = "; ".join(f"{name}: {' '.join(run_options(used[name]))}" for name in results)
    return (
        "\n".join(rows)
        + "\n"
        + verdict(results)
        + f"\nto repeat a row, dgtd run with the comparison's options and its method's: {repeat}"
    )


def verdict(results: dict) -> str:
    """What the table's numbers are, and which method reached the lowest tail-averaged value error (the measure the
    README recommends), with its spread over the seeds; a method with a diverged seed, or no tail average, ranks
    last."""
    import numpy as np

    seeds = max(len(r.info["diverged_at"]) for r in results.values())
    said = (
        f"each number: the worst agent at the end of the run, median over {seeds} seed(s); value tail is the "
        "tail-averaged iterate's value error |Phi (w_tail - w*)|_d / |Phi w*|_d, the output to read"
    )
    tails = {name: np.asarray(r.metrics["value_error_tail"][-1], dtype=float) for name, r in results.items()}
    complete = {name: x for name, x in tails.items() if np.isfinite(x).all()}
    if not complete:
        return said + "\nno method has a tail average on every seed (diverged, or no tail kept): none ranked"
    ranked = sorted(complete, key=lambda name: float(np.median(complete[name])))
    best = complete[ranked[0]]
    line = (
        f"lowest value tail: {ranked[0]}, {np.median(best):.3g} (seeds {best.min():.3g} to {best.max():.3g})"
        + "".join(f"; then {n}, {np.median(complete[n]):.3g}" for n in ranked[1:3])
    )
    unranked = [name for name in tails if name not in complete]
    if unranked:
        line += f"; not ranked (a seed diverged or has no tail average): {', '.join(unranked)}"
    return said + "\n" + line
