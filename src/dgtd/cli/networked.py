"""`dgtd networked TASK`: Qu, Wierman and Li's scalable actor-critic on a networked system (`dgtd.run.networked`),
and `dgtd compare TASK` on one: networked, independent and the task's heuristic on the same keyed numbers."""

from __future__ import annotations

import sys
from contextlib import ExitStack
from dataclasses import asdict, fields
from pathlib import Path

import click

from dgtd.cli.options import declared_option, make_option, output_options
from dgtd.config import field_types
from dgtd.errors import DgtdInputError
from dgtd.run.networked import TASKS, NetworkedConfig

CONFIG, CHECKPOINT = "config.toml", "checkpoint.npz"


def networked_options(command):
    """`NetworkedConfig`'s fields as options (None: not given, the config's default applies)."""
    hints = field_types(NetworkedConfig)
    for f in reversed(fields(NetworkedConfig)):
        help = declared_option(f)["help"] + f"  [default: {f.default}]"
        command = make_option(f.name, f, hints[f.name], help)(command)
    return command


@click.command()
@click.argument("task", required=False)
@networked_options
@output_options("out", "progress", "plots", "overwrite", "checkpoint_every")
@click.option("--ranks", type=int, default=None, help="Spread the agents over R processes: starts the mpi extra's "
              "mpiexec -n R (each holds its agents' actors and critics; the numbers are one process's, bit for "
              "bit).")  # fmt: skip
def networked(task, out, progress, plots, overwrite, checkpoint_every, ranks, **values):
    """Agents with local states learn by Qu, Wierman and Li's scalable actor-critic on a networked TASK
    (wireless-access, the published benchmark by default; epidemic; random-networked) or --problem FILE.npz (a
    networked MDP file: edges, P, R, gamma, start; docs/control.md): each agent's policy on its own
    observation, its critic over its --hops neighbourhood; every --every episodes the policies' mean per-agent
    discounted return from --rollouts keyed rollouts, beside the task's heuristic. Writes config.toml, summary.json,
    metrics.csv, policies.npz and returns.png (docs/control.md, "The wireless-access benchmark"). With
    --checkpoint-every K (episodes) the run's state is kept, and the same command again continues it to the
    uninterrupted numbers."""
    from dgtd.run import runtime
    from dgtd.run.checkpoint import remove_checkpoint
    from dgtd.run.networked import config_from, heuristic, learn_networked, task_of
    from dgtd.run.settings import check_count

    if task not in TASKS and not (task is None and values.get("problem_file")):
        raise DgtdInputError(f"name a networked task: {', '.join(TASKS)}" + (f"; got {task!r}" if task else ""))
    config = config_from(values)
    problem = task_of(task, config.agents, config.problem_file)  # (its size checked before anything is written)
    every = check_count("checkpoint_every", checkpoint_every or 0, 0)
    spread = runtime.ranks() > 1  # (under mpiexec: the agents over the job's ranks)
    if every and (ranks is not None or spread):
        raise DgtdInputError("a networked run over ranks keeps no checkpoint yet: leave out --checkpoint-every, or "
                             "run in one process")  # fmt: skip
    if ranks is not None:
        from dgtd.cli.launch import ARGV, launch

        raise SystemExit(launch(ranks, None, ARGV))
    label = task or problem.name
    out = Path(out) if out else Path("runs") / f"networked-{label}"
    steps = config.steps
    click.echo(
        f"{label}: {problem.n_agents} agents, gamma {problem.gamma:g}; scalable actor-critic, kappa {steps.kappa}, "
        f"horizon {steps.horizon}; {config.episodes:,} episodes x {config.seeds} seed(s), evaluated every "
        f"{config.every:,} by {config.rollouts} rollouts" + (f", over {runtime.ranks()} ranks" if spread else "")
    )
    with ExitStack() as stack:
        claim = runtime.claimed(
            lambda: stack.enter_context(_claimed(out, label, config, overwrite, "learning run")), lambda: None
        )  # (the process that writes holds the folder; the others learn their agents and write nothing)
        so_far, saves = _saves(out, claim, every)
        result = _with_bar(config.episodes, progress and claim is not None,
                           lambda bar: learn_networked(problem, config, bar, so_far, **saves))  # fmt: skip
        if claim is None:
            return
        best = heuristic(task, problem, config)
        written = _write(out, {"scalable": result}, best, claim.record, plots)
        remove_checkpoint(out / CHECKPOINT)  # (the numbers are complete)
    _report({"scalable": result}, best)
    click.echo(f"wrote {out}/{', '.join(written)} ({result['seconds']:.1f} s)")


def _saves(out: Path, claim, every: int) -> tuple:
    """`learn_networked`'s callbacks of the process that writes (``claim`` its `_claimed`; None elsewhere): (each
    evaluation written as it is made, so that a run cut off keeps them; every ``every`` episodes the run's state)."""
    if claim is None:
        return None, {}
    if claim.resume is not None:
        click.echo(f"resuming {out} at episode {int(claim.resume['m']):,}")

    def so_far(episodes, returns):
        _metrics(out, {"scalable": {"episodes": episodes, "return": returns}})

    def keep(snapshot):
        from dgtd.run.checkpoint import save_checkpoint

        save_checkpoint(out / CHECKPOINT, snapshot, claim.record)

    return so_far, {"checkpoint_every": every, "on_checkpoint": keep, "resume": claim.resume}


def compare_networked_cli(task, seeds, out, progress, plots, overwrite, given: dict) -> None:
    """`dgtd compare TASK` on a networked task: networked learners, independent ones and the heuristic, -T episodes
    each, at --agents (the run options beside them refused)."""
    from dgtd.run.networked import compare_networked, config_from, heuristic, task_of

    episodes, agents = given.pop("iterations", None), given.pop("agents", None)
    if given:
        names = ", ".join("--" + k.replace("_", "-") for k in sorted(given))
        raise DgtdInputError(f"{task} is a networked task: `dgtd compare {task}` takes -T, --seeds and --agents; "
                             f"{names} are `dgtd networked {task}`'s or not its (dgtd networked --help)")  # fmt: skip
    config = config_from({"episodes": episodes, "seeds": seeds, "agents": agents})
    problem = task_of(task, config.agents)
    out = Path(out) if out else Path("runs") / f"compare-{task}"
    click.echo(f"{task}: {problem.n_agents} agents; networked and independent learners, {config.episodes:,} episodes x "
               f"{config.seeds} seed(s) each, and the heuristic, on the same keyed numbers")  # fmt: skip
    with _claimed(out, task, config, overwrite, "comparison") as claim:
        results = _with_bar(2 * config.episodes, progress, lambda bar: compare_networked(problem, config, bar))
        best = heuristic(task, problem, config)
        written = _write(out, results, best, claim.record, plots)
    _report(results, best)
    click.echo(f"wrote {out}/{', '.join(written)}")


def record_of(task: str, config: NetworkedConfig) -> dict:
    """What was asked: the task and every option set (a problem file's SHA-256 beside its path)."""
    record = {"task": task, **{k: v for k, v in asdict(config).items() if v is not None}}
    if config.problem_file is not None:
        from dgtd.problems.io import file_digest

        record["problem_sha256"] = file_digest(config.problem_file)
    return record


def _with_bar(total: int, progress: bool, work):
    from tqdm import tqdm

    with tqdm(total=total, disable=not progress, file=sys.stderr, unit="episode", mininterval=0.5) as bar:
        return work(bar.update)


class _claimed:
    """The results folder held (`dgtd.run.owner.Owner`), another run's results refused unless --overwrite, and
    config.toml written: what was asked."""

    def __init__(self, out: Path, task: str, config: NetworkedConfig, overwrite: bool, what: str):
        from dgtd.run.owner import Owner

        self.record = record_of(task, config)
        self.owner, self.out, self.overwrite, self.what = Owner(out, what, overwrite), out, overwrite, what
        self.resume: dict | None = None

    def __enter__(self):
        import tomli_w

        from dgtd.run.atomic import atomic_write
        from dgtd.run.results import refuse_other_results

        self.owner.__enter__()
        try:
            if not self.overwrite:
                refuse_other_results(self.out, self.record, self.what)
            self.resume = self._checkpoint()
            kind = "comparison" if self.what == "comparison" else "run"
            text = f"# dgtd networked {kind}: the options given\n" + tomli_w.dumps({"networked": self.record})
            atomic_write(self.out / CONFIG, text.encode())
        except BaseException:
            self.owner.__exit__(None, None, None)
            raise
        return self

    def __exit__(self, *exc):
        return self.owner.__exit__(*exc)

    def _checkpoint(self) -> dict | None:
        """The snapshot of this very run cut off (its checkpoint, the same options), or None; another run's refused
        unless --overwrite (which starts afresh)."""
        import json

        from dgtd.run.checkpoint import load_checkpoint
        from dgtd.run.results import first_difference

        path = self.out / CHECKPOINT
        if self.overwrite or not path.exists():
            return None
        snapshot, saved = load_checkpoint(path)
        if diff := first_difference(saved, json.loads(json.dumps(self.record))):
            raise DgtdInputError(f"{self.out} holds the checkpoint of another {self.what} ({diff}); choose another "
                                 "--out, or pass --overwrite")  # fmt: skip
        return snapshot


def _write(out: Path, results: dict, h: dict | None, record: dict, plots: bool) -> list:
    """Numbers before pictures, each file atomically: summary.json (``record`` what was asked, ``h`` the best
    heuristic), metrics.csv, policies.npz (one run), returns.png."""
    import numpy as np

    from dgtd.run.atomic import atomic_write, atomic_write_json
    from dgtd.run.results import npz_bytes

    summary = {"config": record, "learners": {}}
    for label, r in results.items():
        summary["learners"][label] = {
            "agents": r["agents"], "episodes": r["episodes"].tolist(), "return": r["return"].tolist(),
            "return_last": r["return"][-1].tolist(), "seconds": r["seconds"],
        }  # fmt: skip
    if h is not None:
        summary["heuristic"] = {"return": h["return"].tolist(), "policy": h["policy"], "of": h["of"]}
    _metrics(out, results)
    atomic_write_json(out / "summary.json", summary)
    written = ["metrics.csv", "summary.json"]
    if len(results) == 1:
        atomic_write(out / "policies.npz", npz_bytes({"policies": np.asarray(results["scalable"]["policies"])}))
        written.append("policies.npz")
    if plots:
        from dgtd.plots.learning import networked_figure

        written.append(networked_figure(out / "returns.png", results, h, record["task"]))
    return written


def _metrics(out: Path, results: dict) -> None:
    """metrics.csv (learner, seed, episode, metric, value) of each learner's evaluations, atomically."""
    from dgtd.run.atomic import atomic_write
    from dgtd.run.results import rows_csv

    rows = [(label, b, int(episode), "return", float(v)) for label, r in results.items()
            for c, episode in enumerate(r["episodes"]) for b, v in enumerate(r["return"][c])]  # fmt: skip
    atomic_write(out / "metrics.csv", rows_csv(rows, "learner", "episode"))


def _report(results: dict, h: dict | None) -> None:
    import numpy as np

    click.echo(f"{'learner':<24} {'start':>8} {'last (median over seeds)':>26} {'seeds range':>20}")
    for label, r in results.items():
        last = r["return"][-1]
        click.echo(f"{label:<24} {np.median(r['return'][0]):8.4f} {np.median(last):26.4f} "
                   f"{last.min():9.4f} to {last.max():.4f}")  # fmt: skip
    if h is not None:
        click.echo(f"{'heuristic (best of ' + str(h['of']) + ')':<24} {'':>8} {np.median(h['return']):26.4f} "
                   f"({h['policy']})")  # fmt: skip
    click.echo("return: the mean per-agent discounted return over the horizon, (1/n) sum_i sum_{t<T} gamma^t r_i(t)")
