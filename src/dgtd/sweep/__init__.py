"""Sweeps: the runs of a [grid] of run fields, handed as jobs to a `concurrent.futures` executor.

Each grid point is one job: a `RunConfig` run with all its seeds side by side. Jobs go to a local process
pool by default, or to Ray (`dgtd.sweep.ray`); the driver alone writes files (`dgtd.run.store`), so workers
on other machines need no shared disk. A job whose worker dies is run again: Ray retries it itself, and a
broken process pool is replaced and the unfinished jobs resubmitted.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import os
import sys
from collections.abc import Callable
from concurrent.futures import Executor, ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, replace
from pathlib import Path

from dgtd.config import (
    ALGORITHM_FIELDS,
    Output,
    RunConfig,
    field_types,
    flat,
    make_source,
    resolve,
    spec_record,
    unflat,
)
from dgtd.errors import DgtdInputError
from dgtd.experiments import TABLES, Experiment, SweepOptions, absolute_paths, to_toml
from dgtd.run.owner import Owner
from dgtd.run.store import SweepStore

MAX_ATTEMPTS = 3


@dataclass(frozen=True)
class Job:
    """One grid point: ``point`` maps grid keys ('alpha0', 'params.n_states') to values, None where the job's
    algorithm has no such field; ``config`` is the fully resolved config; ``id`` a digest of it."""

    id: str
    point: dict
    config: RunConfig


def grid_keys(grid: dict) -> list[tuple[str, list]]:
    """[(key, values)] with nested tables flattened to 'params.x' keys, in the file's order."""
    out = []
    for key, values in grid.items():
        if key in TABLES:
            out += [(f"{key}.{sub}", vals) for sub, vals in values.items()]
        else:
            out.append((key, values))
    return out


def apply_point(config: RunConfig, point: dict) -> RunConfig:
    """``config`` with a grid point's values set (by flat name), then the fields its algorithm lacks cleared (kappa
    for td0)."""
    spec = flat(config)
    over, tables = {}, {t: dict(spec[t] or {}) for t in TABLES}
    for key, value in point.items():
        table, _, sub = key.partition(".")
        if sub:
            tables[table][sub] = value
        else:
            over[key] = value
    spec.update(over, **{t: d or None for t, d in tables.items()})
    if spec["algorithm"] is not None:
        from dgtd.algorithms import ALGORITHMS

        if spec["algorithm"] in ALGORITHMS:
            own = field_types(ALGORITHMS[spec["algorithm"]])
            spec.update({k: None for k in ALGORITHM_FIELDS if k not in own})
            spec["algorithm_params"] = {k: v for k, v in (spec["algorithm_params"] or {}).items() if k in own} or None
    return unflat(spec, config.output)


def _applied(config: RunConfig, key: str):
    spec = flat(config)
    table, _, sub = key.partition(".")
    return (spec[table] or {}).get(sub) if sub else spec[key]


def expand(exp: Experiment) -> list[Job]:
    """The sweep's jobs in grid order (the product of the grid's lists), each resolved and checked.

    Grid points that resolve to the same run (kappa for an algorithm without kappa) are one job.
    """
    keys = grid_keys(exp.grid)
    jobs, seen = [], set()
    for values in itertools.product(*(v for _, v in keys)):
        point = dict(zip((k for k, _ in keys), values, strict=True))
        config = absolute_paths(apply_point(exp.config, point))
        try:
            resolved = resolve(config).config
        except DgtdInputError as e:
            where = ", ".join(f"{k} = {v!r}" for k, v in point.items())
            raise DgtdInputError(f"grid point {where}: {e}") from None
        record = json.dumps(spec_record(resolved), sort_keys=True)
        job_id = "j" + hashlib.sha256(record.encode()).hexdigest()[:12]
        if job_id not in seen:
            seen.add(job_id)
            jobs.append(Job(job_id, {k: _applied(config, k) for k in point}, resolved))
    return jobs


def run_job(spec: dict, threads: int | None = 1) -> dict:
    """Run one job (in a worker): its checkpoint steps, metrics (C, seeds) and summary, as plain data.

    ``threads`` caps the compiled kernels' threads, so that a worker per core does not oversubscribe.
    """
    from dgtd.run.loop import run as run_loop
    from dgtd.run.results import summary

    problem, network, algorithm, sampling, settings, resolved, channel = resolve(unflat(spec))
    cap_threads(threads, settings.backend)
    source = make_source(resolved, settings)
    result = run_loop(problem, network, algorithm, sampling, settings, source=source, channel=channel)
    return {
        "steps": result.steps,
        "metrics": result.metrics,
        "algorithm": algorithm.name,
        "summary": summary(result, json.loads(json.dumps(spec_record(resolved)))),
    }


@dataclass(frozen=True)
class Sweep:
    """What the runner needs of a sweep, of runs or of learning runs (`dgtd.sweep.learning`): its executor
    ``options``, its ``grid`` keys, the ``config_toml`` that reruns it, and for a job, ``work(job) -> (function,
    args)`` run in a worker (a module-level function: it travels to other processes) and ``job_toml(job)``, the job's
    own config."""

    options: SweepOptions
    grid: list
    config_toml: str
    work: Callable
    job_toml: Callable


def cap_threads(threads: int | None, backend: str) -> None:
    """A worker's compiled kernels at most ``threads`` threads, so that a worker per core does not oversubscribe."""
    if threads and backend == "numba":
        import numba

        numba.set_num_threads(min(int(threads), numba.config.NUMBA_NUM_THREADS))  # type: ignore[attr-defined]


def make_executor(opts: SweepOptions, n_jobs: int) -> Executor:
    """A process pool on the local cores, or a `RayExecutor` (local on 127.0.0.1, or ``address``)."""
    if opts.executor == "ray":
        from dgtd.sweep.ray import RayExecutor

        return RayExecutor(address=opts.address, num_cpus=opts.workers)
    if opts.address is not None:
        raise DgtdInputError("address names a Ray cluster; use it with executor = 'ray' (--executor ray)")
    import multiprocessing

    workers = max(1, min(opts.workers or os.cpu_count() or 1, n_jobs))
    # spawn, not fork: workers start clean (no inherited threads of the compiled kernels' runtime)
    return ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"))


def default_out(file: str | None) -> Path:
    return Path("runs") / (Path(file).stem if file else "sweep")


def _work(sweep: Sweep, job) -> tuple:
    function, args = sweep.work(job)
    return (function, *args)


def run_sweep(exp: Experiment, out: Path, echo=print, progress: bool = True) -> dict:
    """Run the jobs of ``exp`` not yet finished in ``out``.

    Returns {'jobs', 'skipped', 'ran', 'failed' {id: message}, 'table' (path or None), 'seconds'}.
    """
    import time

    t_start = time.perf_counter()
    if not exp.grid:
        raise DgtdInputError(
            "a sweep needs a [grid] table of lists, e.g. [grid] alpha0 = [1.0, 10.0]; use `dgtd run` for a single run"
        )
    jobs = expand(exp)
    output = Output(out=str(Path(out).resolve()), progress=exp.config.output.progress)
    saved = replace(exp, config=replace(absolute_paths(exp.config), output=output))
    sweep = Sweep(
        exp.sweep, [k for k, _ in grid_keys(exp.grid)],
        to_toml(saved, "A dgtd sweep: `dgtd sweep THIS_FILE` runs it again, skipping finished jobs."),
        lambda job: (run_job, (flat(job.config), 1)),
        lambda job: to_toml(Experiment(job.config), "One job of a dgtd sweep: `dgtd run THIS_FILE` runs it alone."),
    )  # fmt: skip
    return run_jobs(sweep, jobs, out, exp.config.output.overwrite, echo, progress, t_start)


def run_jobs(sweep: Sweep, jobs: list, out: Path, overwrite: bool, echo, progress: bool, t_start: float) -> dict:
    """Run the ``jobs`` of ``sweep`` not yet finished in ``out`` (the directory claimed while it runs)."""
    out = Path(out).resolve()
    resume = sweep.options.resume if sweep.options.resume is not None else out.exists()
    with Owner(out, "sweep", overwrite):  # the directory is this sweep's until it ends
        return _sweep_into(sweep, jobs, out, resume, echo, progress, t_start)


def _sweep_into(sweep: Sweep, jobs: list, out: Path, resume: bool, echo, progress: bool, t_start: float) -> dict:
    """`run_jobs`' work once ``out`` is its own."""
    import time

    from tqdm import tqdm

    store = SweepStore(out, sweep.options.format)
    store.begin(sweep.config_toml)
    todo = [j for j in jobs if not (resume and store.done(j.id))]
    opts = sweep.options
    where = opts.address or ("a local Ray on 127.0.0.1" if opts.executor == "ray" else "a local process pool")
    echo(
        f"{len(jobs)} jobs ({len(jobs) - len(todo)} already finished), {len(todo)} to run on {where}; results in {out}"
    )
    failed: dict[str, str] = {}
    bar = tqdm(total=len(todo), unit="job", file=sys.stderr, disable=not progress, smoothing=0.1)
    try:
        if todo:
            _run_jobs(sweep, todo, store, failed, bar, echo)
    finally:
        bar.close()
        table = store.write_table([(j.id, j.point) for j in jobs])
        status = lambda j: "failed" if j.id in failed else ("finished" if store.done(j.id) else "not run")  # noqa: E731
        from dgtd.run.results import atomic_write_json

        atomic_write_json(
            out / "sweep.json",
            {
                "grid": sweep.grid,
                "table": None if table is None else table.name,
                "jobs": [{"job": j.id, "point": j.point, "status": status(j)} for j in jobs],
            },
        )
    return {
        "jobs": len(jobs),
        "skipped": len(jobs) - len(todo),
        "ran": len(todo) - len(failed),
        "failed": failed,
        "table": table,
        "seconds": time.perf_counter() - t_start,
    }


def _run_jobs(sweep: Sweep, todo: list, store: SweepStore, failed: dict, bar, echo) -> None:
    """Submit jobs until each is finished or failed; a broken process pool is replaced (Ray retries itself)."""
    pending = {j.id: j for j in todo}
    attempts = dict.fromkeys(pending, 0)
    while pending:
        executor = make_executor(sweep.options, len(pending))
        broken = False
        try:
            futures = {executor.submit(*_work(sweep, j)): j for j in pending.values()}
            for future in as_completed(futures):
                job = futures[future]
                try:
                    result = future.result()
                except BrokenProcessPool:
                    broken = True
                    attempts[job.id] += 1
                    if attempts[job.id] < MAX_ATTEMPTS:
                        continue  # resubmitted on a fresh pool
                    message = f"its worker process died {MAX_ATTEMPTS} times"
                except Exception as e:  # a job's own failure must not stop the others
                    message = f"{type(e).__name__}: {e}"
                else:
                    store.write_job(job.id, job.point, sweep.job_toml(job), result)
                    del pending[job.id]
                    bar.update()
                    continue
                failed[job.id] = message
                store.write_error(job.id, message)
                del pending[job.id]
                bar.update()
        finally:
            executor.shutdown(wait=False, cancel_futures=True)
        if broken and pending:
            bar.clear()
            echo(f"a worker process died; {len(pending)} unfinished job(s) go to a fresh pool")
