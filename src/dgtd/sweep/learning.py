"""Sweeps of learning runs: `dgtd sweep FILE` where FILE has a [learn] table, the options of `dgtd learn` by their flat
names (``task`` among them), and a [grid] of lists of those options' values:

    [learn]
    task = "pull-away"
    iterations = 20000
    seeds = 4

    [grid]
    actor_step = [0.1, 0.5]
    algorithm = ["dgtd", "consensus-td0"]

Each grid point is one job, a `dgtd learn` run with all its seeds side by side, checked before any runs and handed to
the same executors and store as a sweep of runs (`dgtd.sweep.run_jobs`): one long table (job, the point, learners,
seed, step, metric, value) and per job its summary.json, its arrays and its options (OUT/jobs/ID.toml, a [learn]
table). A [sweep] table sets the executor as for runs.
"""

from __future__ import annotations

import hashlib
import itertools
import json
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from dgtd.config import check_type, field_types
from dgtd.errors import DgtdInputError
from dgtd.experiments import Experiment, SweepOptions, check_choices, flat_type, sweep_fields
from dgtd.learning import SHARED, LearnConfig, resolve_learning

OWN = field_types(LearnConfig)
OPTIONS = ("task", *OWN, *SHARED)  # what a [learn] table and its [grid] may set


def is_learning(data: dict) -> bool:
    """Whether a sweep file's data is a learning sweep's (it has a [learn] table)."""
    return isinstance(data.get("learn"), dict)


def _typed(key: str, value, where: str):
    if key not in OPTIONS:
        from dgtd.config import closest

        raise DgtdInputError(f"unknown field {key!r} in {where}{closest(key, OPTIONS)}")
    kind = str if key == "task" else OWN[key] if key in OWN else flat_type(key)
    return check_type(f"{key} in {where}", value, kind)


def parse(data: dict, where: str, flags: dict) -> tuple[dict, dict, SweepOptions]:
    """(the base options, the grid {option: [values]}, the executor's options) of a learning sweep file's ``data``,
    each checked; ``flags`` typed on the command line set base options (the grid's values win)."""
    unknown = sorted(set(data) - {"learn", "grid", "sweep"})
    if unknown:
        raise DgtdInputError(f"a learning sweep ({where}) has [learn], [grid] and [sweep] tables, not {unknown[0]!r}")
    base = {k: _typed(k, v, f"[learn] of {where}") for k, v in data["learn"].items()}
    base |= {k: _typed(k, v, "the command line") for k, v in flags.items() if v is not None}
    grid = {}
    for key, values in check_type(f"[grid] in {where}", data.get("grid", {}), dict).items():
        if not isinstance(values, list) or not values:
            raise DgtdInputError(f"grid.{key} in {where} must be a non-empty list of values, e.g. {key} = [..]")
        grid[key] = [_typed(key, v, f"[grid] of {where}") for v in values]
    if not grid:
        raise DgtdInputError(
            "a sweep needs a [grid] table of lists, e.g. [grid] actor_step = [0.1, 0.5]; use `dgtd learn` for one run"
        )
    options = SweepOptions(**sweep_fields(data.get("sweep", {}), where))
    check_choices(Experiment(sweep=options))
    return base, grid, options


@dataclass(frozen=True)
class LearnJob:
    """One grid point: ``point`` its grid values, ``values`` every option of its `dgtd learn` run (flat names, task
    among them), ``id`` a digest of what it resolves to."""

    id: str
    point: dict
    values: dict


def expand(base: dict, grid: dict) -> list[LearnJob]:
    """The sweep's jobs in grid order (the product of the grid's lists), each resolved and checked; points that
    resolve to the same run are one job."""
    jobs, seen = [], set()
    for combination in itertools.product(*grid.values()):
        point = dict(zip(grid, combination, strict=True))
        values = base | point
        try:
            record = resolve_learning(values.get("task"), _options(values)).record
        except DgtdInputError as e:
            where = ", ".join(f"{k} = {v!r}" for k, v in point.items())
            raise DgtdInputError(f"grid point {where}: {e}") from None
        job_id = "j" + hashlib.sha256(json.dumps(record, sort_keys=True).encode()).hexdigest()[:12]
        if job_id not in seen:
            seen.add(job_id)
            jobs.append(LearnJob(job_id, point, values))
    return jobs


def _options(values: dict) -> dict:
    """Every option `dgtd.learning.resolve_learning` reads, None where not set."""
    return {name: values.get(name) for name in (*(f.name for f in fields(LearnConfig)), *SHARED)}


def run_learning_job(values: dict, threads: int | None = 1) -> dict:
    """Run one learning job (in a worker): its checkpoint steps, metrics (checkpoints, seeds) and summary."""
    from dgtd.run.learn import summary
    from dgtd.run.schemes import run_job
    from dgtd.sweep import cap_threads

    job = resolve_learning(values.get("task"), _options(values))
    cap_threads(threads, job.settings.backend)
    problem = job.env if job.env is not None else job.mdp
    result = run_job(job)
    return {
        "steps": result.steps,
        "metrics": result.metrics,
        "algorithm": f"{job.settings.actor}/{job.critic.name}",
        "summary": summary(result, problem, json.loads(json.dumps(job.record))),
    }


def run_learning_sweep(data: dict, where: str, out: Path, flags: dict, overwrite: bool, echo, progress: bool) -> dict:
    """Run the jobs of a learning sweep file's ``data`` not yet finished in ``out`` (`dgtd.sweep.run_jobs`)."""
    import time

    import tomli_w

    from dgtd.sweep import Sweep, run_jobs

    t_start = time.perf_counter()
    base, grid, options = parse(data, where, flags)
    jobs = expand(base, grid)
    rerun = {"learn": base, "grid": grid} | ({"sweep": _set(options)} if _set(options) else {})
    again = "# A dgtd learning sweep: `dgtd sweep THIS_FILE` runs it again, skipping finished jobs.\n"
    one = "# One job of a dgtd learning sweep: its `dgtd learn` options.\n"
    sweep = Sweep(
        options, list(grid), again + tomli_w.dumps(rerun), lambda job: (run_learning_job, (job.values, 1)),
        lambda job: one + tomli_w.dumps({"learn": job.values}),
    )  # fmt: skip
    return run_jobs(sweep, jobs, out, overwrite, echo, progress, t_start)


def _set(options: SweepOptions) -> dict[str, Any]:
    """The executor's options that differ from their defaults."""
    default = SweepOptions()
    return {
        f.name: getattr(options, f.name)
        for f in fields(options)
        if getattr(options, f.name) != getattr(default, f.name) and getattr(options, f.name) is not None
    }
