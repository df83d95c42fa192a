"""The `dgtd` command line: run, solve, scenarios, compare. Bad input prints one line and exits with code 2."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click
import numpy as np

from dgtd.errors import DgtdInputError


def _problem_options(f):
    f = click.option("--problem", "problem_file", type=str, default=None,
                     help="An .npz with arrays P (S,S), R (N,S), Phi (S,q) and scalar gamma, instead of a scenario.")(f)
    f = click.option("--graph", type=str, default=None,
                     help="ring, path, star, complete, erdos-renyi, or a file of 'i j' edge lines (default: the scenario's, else ring).")(f)
    f = click.option("--edge-prob", type=float, default=None,
                     help="Probability that each edge of the graph is up at each step (1 = fixed graph).")(f)
    f = click.option("--kappa", type=float, default=None, help="Weight of the consensus term of eq. (Lagrangian2).")(f)
    f = click.option("--rho", type=float, default=None, help="Regulariser (rho/2)|mu|^2 - (rho/2)|w|^2 (0 = none).")(f)
    return f


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="dgtd")
def cli():
    """dgtd: distributed policy evaluation with the primal-dual distributed GTD method (Algorithm 1)."""


@cli.command()
@click.argument("scenario", required=False)
@_problem_options
@click.option("--iterations", "-T", type=int, default=None, help="Number of iterations T (default: the scenario's).")
@click.option("--seeds", type=int, default=1, show_default=True, help="Independent runs, side by side.")
@click.option("--seed", type=int, default=0, show_default=True, help="Base seed; seed k uses SeedSequence(seed, spawn_key=(k,)).")
@click.option("--alpha0", type=float, default=None, help="Step-size scale alpha0.")
@click.option("--beta", type=float, default=None, help="Step-size offset beta in alpha0/sqrt(k+beta).")
@click.option("--schedule", type=click.Choice(["sqrt", "harmonic", "constant"]), default=None,
              help="alpha0/sqrt(k+beta) (the paper's), alpha0/(k+beta), or constant alpha0.")
@click.option("--sampling", type=click.Choice(["iid", "markov"]), default=None, help="i.i.d. s ~ d or Markovian trajectories.")
@click.option("--shared/--independent", default=None,
              help="All agents observe one state trajectory (scenario 1), or each its own copy (scenario 2).")
@click.option("--reward-noise", type=click.Choice(["none", "bernoulli", "uniform"]), default=None,
              help="Random rewards in [0, sigma] with the model's mean (default: deterministic).")
@click.option("--backend", type=click.Choice(["numba", "numpy"]), default="numba", show_default=True)
@click.option("--checkpoints", type=int, default=200, show_default=True, help="How many times to record metrics.")
@click.option("--tail-fraction", type=float, default=0.5, show_default=True, help="Final fraction of the run averaged for w_tail.")
@click.option("--out", type=click.Path(file_okay=False), default=None, help="Results directory (default: runs/NAME).")
@click.option("--progress/--no-progress", default=True, show_default=True)
@click.option("--plots/--no-plots", default=True, show_default=True)
def run(scenario, problem_file, graph, edge_prob, kappa, rho, iterations, seeds, seed, alpha0, beta, schedule,
        sampling, shared, reward_noise, backend, checkpoints, tail_fraction, out, progress, plots):
    """Run Algorithm 1 on a named SCENARIO (e.g. paper-example-1) or on --problem FILE.npz."""
    from tqdm import tqdm

    from dgtd.config import RunSpec, make_source, resolve, scenario_of, spec_record
    from dgtd.run.loop import run as run_loop
    from dgtd.run.results import write_results

    if scenario is None and problem_file is None:
        raise DgtdInputError("name a scenario (dgtd scenarios lists them) or give --problem FILE.npz")
    spec = RunSpec(scenario=scenario, problem_file=problem_file, graph=graph, edge_prob=edge_prob, iterations=iterations,
                   seeds=seeds, seed=seed, alpha0=alpha0, beta=beta, schedule=schedule, kappa=kappa, rho=rho,
                   sampling=sampling, shared=shared, reward_noise=reward_noise, backend=backend,
                   checkpoints=checkpoints, tail_fraction=tail_fraction)
    problem, network, algorithm, samp, settings, resolved = resolve(spec)
    out = Path(out) if out else Path("runs") / problem.name
    source = make_source(resolved, settings)  # None: samples from the model; else a simulator's own
    links = getattr(source, "describe", network.describe)()
    click.echo(f"{problem.name}: {problem.n_states} states, {problem.n_agents} agents, {problem.n_features} features, "
               f"gamma {problem.gamma:g}{', off-policy' if problem.off_policy else ''}; network: {links}")
    click.echo(f"Algorithm 1: alpha_k = {algorithm.alpha0:g}/{'sqrt(k+' if algorithm.schedule == 'sqrt' else '(k+'}"
               f"{algorithm.beta:g}){'' if algorithm.schedule != 'constant' else ' (constant)'}, kappa {algorithm.kappa:g}, "
               f"rho {algorithm.rho:g}; {settings.iterations:,} iterations x {settings.seeds} seed(s), {samp.mode} sampling, "
               f"{'shared' if samp.shared else 'independent'} states, {settings.backend} backend")
    bar = tqdm(total=settings.iterations, unit="it", unit_scale=True, disable=not progress, file=sys.stderr, mininterval=0.5)
    try:
        result = run_loop(problem, network, algorithm, samp, settings, progress=bar.update, source=source)
    finally:
        bar.close()
    sc = scenario_of(resolved)
    extra, text = sc.report(result, source, out, plots) if sc is not None and sc.report is not None else (None, "")
    write_results(out, result, spec_record(resolved), extra=extra)
    if plots:
        from dgtd.plots import plot_errors, plot_iterates

        plot_iterates(result, out / "iterates.png")
        plot_errors(result, out / "errors.png")
    click.echo(final_table(result))
    if text:
        click.echo(text)
    click.echo(f"wrote {out}/summary.json, metrics.csv, trajectory.npz{', iterates.png, errors.png' if plots else ''} "
               f"({result.seconds:.1f} s)")


def _vec(x, n=4) -> str:
    s = ", ".join(f"{v:.4g}" for v in x[:n])
    return f"({s}{', ...' if len(x) > n else ''})"


def final_table(result) -> str:
    """Every agent's last and averaged w beside w* (seed 0), then the worst errors over seeds."""
    from dgtd.problems import exact

    e_last = exact.relative_error(result.w_last, result.w_star)
    e_avg = exact.relative_error(result.w_avg, result.w_star)
    e_tail = exact.relative_error(result.w_tail, result.w_star)
    cons = exact.consensus_error(result.w_last)
    rows = [f"w* = {_vec(result.w_star, 8)}   (relative errors are |w_i - w*|_inf / |w*|_inf)",
            f"{'agent':>5}  {'w_last (seed 0)':<34}{'err':>8}  {'w_avg (seed 0)':<34}{'err':>8}  {'w_tail err':>10}"]
    for i in range(result.w_last.shape[1]):
        rows.append(f"{i + 1:>5}  {_vec(result.w_last[0, i]):<34}{e_last[0, i]:>8.2%}  {_vec(result.w_avg[0, i]):<34}"
                    f"{e_avg[0, i]:>8.2%}  {e_tail[0, i]:>10.2%}")
    rows.append(f"consensus error sum_i |w_i - mean w|^2 (last, seed 0): {cons[0]:.3g}")
    if result.w_last.shape[0] > 1:
        rows.append(f"over {result.w_last.shape[0]} seeds, worst agent: last {e_last.max():.2%}, averaged {e_avg.max():.2%}, "
                    f"tail-averaged {e_tail.max():.2%}; consensus error max {cons.max():.3g}")
    return "\n".join(rows)


@cli.command()
@click.argument("scenario", required=False)
@_problem_options
def solve(scenario, problem_file, graph, edge_prob, kappa, rho):
    """Print the exact solution (w*, theta*, v* = 0, mu*, d, bounds) of a problem as JSON."""
    from dgtd.config import RunSpec, resolve
    from dgtd.problems import exact
    from dgtd.run.loop import resolve_boxes

    if scenario is None and problem_file is None:
        raise DgtdInputError("name a scenario (dgtd scenarios lists them) or give --problem FILE.npz")
    spec = RunSpec(scenario=scenario, problem_file=problem_file, graph=graph, edge_prob=edge_prob, kappa=kappa, rho=rho)
    problem, network, algorithm, *_ = resolve(spec)
    m = exact.Moments(problem)
    L = network.mean_laplacian()
    sp = exact.saddle_point(m, L, algorithm.kappa, algorithm.rho)
    w = exact.w_star(m)
    out = {
        "problem": problem.name, "n_states": problem.n_states, "n_agents": problem.n_agents,
        "n_features": problem.n_features, "gamma": problem.gamma, "off_policy": problem.off_policy,
        "w_star": w.tolist(), "theta_star": sp.theta.tolist(), "v_star": sp.v.tolist(), "mu_star": sp.mu.tolist(),
        "w_star_per_agent_reward": exact.fixed_point(m, m.b).tolist(),
        "stationary_distribution": m.d.tolist(), "mspbe_w_star": float(exact.mspbe(m, w)),
        "value_function": exact.value_function(m).tolist(), "approximate_values": (problem.Phi @ w).tolist(),
        "mean_laplacian": L.tolist(),
        "kkt_residuals": exact.kkt_residuals(m, L, algorithm.kappa, algorithm.rho, sp),
        "boxes": dict(zip(("theta", "v", "mu", "w"), resolve_boxes(algorithm, m, network), strict=True)),
        "kappa": algorithm.kappa, "rho": algorithm.rho,
    }
    click.echo(json.dumps(out, indent=2))


@cli.command()
@click.option("--cases", default="A,B,C,D,E", show_default=True, help="Which configurations (see dgtd.bench.CASES).")
@click.option("--backend", "backends", default="numba,numpy", show_default=True, help="Backends to measure.")
@click.option("--repeats", type=int, default=3, show_default=True, help="Runs per measurement; the median is reported.")
@click.option("--out", type=click.Path(file_okay=False), default="bench", show_default=True)
def bench(cases, backends, repeats, out):
    """Measure agent-steps per second on the standard configurations; writes JSON and a Markdown table."""
    from dgtd.bench import CASES, markdown, measure
    from dgtd.run.results import atomic_write, atomic_write_json

    keys = [k.strip().upper() for k in cases.split(",")]
    unknown = [k for k in keys if k not in CASES]
    if unknown:
        raise DgtdInputError(f"unknown benchmark case(s) {', '.join(unknown)}; choose from {', '.join(CASES)}")
    report = measure(keys, tuple(b.strip() for b in backends.split(",")), repeats, progress=click.echo)
    atomic_write_json(Path(out) / "throughput.json", report)
    atomic_write(Path(out) / "throughput.md", (markdown(report) + "\n").encode())
    click.echo(markdown(report))


@cli.command()
def scenarios():
    """List the named scenarios."""
    from dgtd.problems.scenarios import SCENARIOS

    for name, builder in SCENARIOS.items():  # the builders' first doc lines: listing builds nothing
        click.echo(f"{name:<20} {(builder.__doc__ or '').strip().splitlines()[0]}")


from dgtd.cli_compare import compare as _compare  # noqa: E402

cli.add_command(_compare)


def main(argv=None) -> None:
    """Entry point: one line and exit code 2 for bad input, never a traceback."""
    try:
        cli.main(args=argv, prog_name="dgtd", standalone_mode=False)
    except DgtdInputError as e:
        click.echo(f"dgtd: error: {e}", err=True)
        sys.exit(2)
    except click.exceptions.Exit as e:
        sys.exit(e.exit_code)
    except click.ClickException as e:
        click.echo(f"dgtd: error: {e.format_message()}", err=True)
        sys.exit(e.exit_code)
    except click.exceptions.Abort:
        click.echo("dgtd: interrupted; files already written are complete", err=True)
        sys.exit(130)
    except KeyboardInterrupt:
        click.echo("dgtd: interrupted; files already written are complete", err=True)
        sys.exit(130)
    except (MemoryError, OSError) as e:
        click.echo(f"dgtd: error: {e}", err=True)
        sys.exit(2 if isinstance(e, OSError) else 1)


if __name__ == "__main__":
    main()
