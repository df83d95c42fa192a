"""Several algorithms on one problem and the same sample streams, with optional step-size tuning.

Every algorithm runs with the same base seed and seed ids, so seed k of every algorithm sees the same
states, rewards and links (`dgtd.sources.model`): differences between algorithms are the algorithms'.
Tuning runs use base seed ``seed + TUNE_SEED_OFFSET``: streams independent of the reported ones.
"""

from __future__ import annotations

import csv
import io
import json
import shutil
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from dgtd.algorithms import ALGORITHMS, make_algorithm
from dgtd.algorithms.base import FixedPoint
from dgtd.errors import DgtdInputError
from dgtd.fields import run_options
from dgtd.problems import exact
from dgtd.problems.model import Problem
from dgtd.run.loop import RunResult, RunSettings, run
from dgtd.run.results import (
    atomic_write,
    bands_csv,
    json_bytes,
    metrics_rows,
    npz_bytes,
    problem_fields,
    reference,
    refuse_other_results,
    write_all,
)

TUNE_SEED_OFFSET = 1_000_003
TUNE_GRID = (0.1, 1 / 3, 1.0, 3.0, 10.0)


@dataclass(frozen=True)
class CompareSettings:
    """What to compare and how: algorithm names, run settings shared by all, and tuning.

    - ``tune``: pick each algorithm's alpha0 from ``alpha0 x tune_grid`` by `tune_score` on ``tune_seeds``
      seeds of base seed ``settings.seed + TUNE_SEED_OFFSET``, then run the reported seeds with it.
    """

    algorithms: tuple[str, ...]
    settings: RunSettings
    tune: bool = False
    tune_seeds: int = 2
    tune_grid: tuple[float, ...] = TUNE_GRID

    def __post_init__(self):
        if not self.algorithms:
            raise DgtdInputError("name at least one algorithm (e.g. --algorithms dgtd,gtd2)")
        unknown = [a for a in self.algorithms if a not in ALGORITHMS]
        if unknown:
            raise DgtdInputError(f"unknown algorithm(s) {', '.join(unknown)}; known: {', '.join(ALGORITHMS)}")
        if len(set(self.algorithms)) != len(self.algorithms):
            raise DgtdInputError(f"an algorithm is named twice in {','.join(self.algorithms)}")
        if int(self.tune_seeds) < 1:
            raise DgtdInputError(f"tune seeds must be >= 1, got {self.tune_seeds}")


def configs_for(scenario, names) -> dict:
    """Each algorithm's config on a scenario: the scenario's own algorithm as the scenario sets it; another takes the
    scenario's step-size schedule and offset (beta); then ``scenario.compare_settings[name]``, the steps tuned on
    the task (`dgtd.scenarios.tuned`) or a problem file's (`dgtd.scenarios.user.problem_compare_steps`), applies."""
    out = {}
    for name in names:
        fields = scenario.compare_settings.get(name, {})
        if name == scenario.algorithm.name:
            out[name] = replace(scenario.algorithm, **fields)
        else:
            steps = {"schedule": scenario.algorithm.schedule, "beta": scenario.algorithm.beta}
            out[name] = make_algorithm(name, **{**steps, **fields})
    return out


def tune_score(result: RunResult) -> float:
    """Median over seeds of the mean log10 worst-agent error (last iterate) over the checkpoints in the
    second half of the run: rewards both speed and final accuracy. +inf if any seed diverged."""
    if np.any(result.info["diverged_at"] >= 0):
        return float("inf")
    late = result.steps >= result.steps[-1] / 2
    err = np.maximum(result.metrics["error_last"][late], 1e-300)
    return float(np.median(np.log10(err).mean(axis=0)))


def error_area(result: RunResult, metric: str = "value_error_last") -> np.ndarray:
    """The area under each seed's error curve, per step: the mean of the worst agent's ``metric`` over the run's
    steps, each checkpoint's value held over the steps since the one before (the checkpoints are not evenly
    spaced). Every value is capped at 1, the relative value error of the start w0 (predicting nothing), and a
    diverged seed counts 1 from its divergence on: a diverged run scores as one that stopped learning, so the area
    is a number in [0, 1] for every run, and medians and ranks over runs are defined (RL-Glue suites report the
    same mean error; they drop or flag diverged runs instead)."""
    err = np.asarray(result.metrics[metric], dtype=np.float64)
    err = np.where(np.isfinite(err), np.minimum(err, 1.0), 1.0)
    held = np.diff(np.concatenate([[0], result.steps])).astype(np.float64)
    return held @ err / float(result.steps[-1])


def _source(source_factory, settings: RunSettings):
    """A fresh simulator source for ``settings`` (so that every run replays the same streams), or None."""
    return None if source_factory is None else source_factory(settings.seed, range(settings.seeds))


def tune(
    problem,
    network,
    sampling,
    algorithm,
    settings: RunSettings,
    grid=TUNE_GRID,
    seeds: int = 2,
    source_factory=None,
    channel=None,
):
    """(best config, table of (alpha0, score)) over ``algorithm.alpha0 x grid`` on the tuning seeds."""
    tune_settings = replace(settings, seeds=int(seeds), seed=settings.seed + TUNE_SEED_OFFSET)
    table = []
    for factor in grid:
        cand = replace(algorithm, alpha0=float(algorithm.alpha0 * factor))
        source = _source(source_factory, tune_settings)
        r = run(problem, network, cand, sampling, tune_settings, source=source, channel=channel)
        table.append((cand.alpha0, tune_score(r)))
    best = min(range(len(table)), key=lambda i: (table[i][1], -table[i][0]))
    return replace(algorithm, alpha0=table[best][0]), table


def compare(
    problem,
    network,
    sampling,
    configs: dict,
    cs: CompareSettings,
    progress=None,
    log=None,
    source_factory=None,
    done=None,
    on_finished=None,
    kernel_ready=None,
    channel=None,
):
    """Run every config on the same streams (and the same ``channel``); returns ({name: RunResult}, {name: config},
    {name: tuning table}).

    ``source_factory(seed, seed_ids)``: a scenario's simulator (`dgtd.scenarios.Scenario.source`);
    each run gets a fresh one, so every algorithm sees the same samples and links. ``done``: the three dicts to
    fill in as each algorithm finishes (default: new ones), so that a caller interrupted half-way still holds the
    finished algorithms' results; algorithms already in ``done`` (a resumed comparison) are not run again.
    ``on_finished(name, result, config, table)`` is called as each algorithm finishes (to save it);
    ``kernel_ready(seconds)`` once each run's kernels are loaded or compiled (`dgtd.run.loop.run`), so that a
    progress bar can leave the compilation out of its rate.
    """
    results, used, tables = ({}, {}, {}) if done is None else done
    for name in cs.algorithms:
        if name in results:
            continue
        alg = configs[name]
        if cs.tune:
            alg, tables[name] = tune(
                problem, network, sampling, alg, cs.settings, cs.tune_grid, cs.tune_seeds, source_factory, channel
            )
            if log is not None:
                log(
                    f"{name}: alpha0 = {alg.alpha0:g} (tuning scores "
                    + ", ".join(f"{a:.3g}: {s:.3g}" for a, s in tables[name])
                    + ")"
                )
        used[name] = alg
        results[name] = run(
            problem,
            network,
            alg,
            sampling,
            cs.settings,
            progress=None if progress is None else (lambda n, name=name: progress(name, n)),
            source=_source(source_factory, cs.settings),
            kernel_ready=kernel_ready,
            channel=channel,
        )
        if on_finished is not None:
            on_finished(name, results[name], used[name], tables.get(name, []))
    return results, used, tables


def compare_csv(results: dict) -> bytes:
    """Long format: algorithm, seed, step, metric, value for every algorithm, checkpoint, seed and metric
    (the run's metrics, then its counts: samples, messages, diverged)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["algorithm", "seed", "step", "metric", "value"])
    for name, result in results.items():
        w.writerows(metrics_rows(result, name))
        counts = result.info["counts"]
        for metric, values in counts.items():
            for c, step in enumerate(result.steps):
                for b in range(values.shape[1]):
                    w.writerow([name, b, int(step), metric, float(values[c, b])])
    return buf.getvalue().encode()


def _stats(x: np.ndarray) -> dict:
    x = np.asarray(x, dtype=np.float64)
    ok = x[np.isfinite(x)]
    if ok.size == 0:
        return {"median": None, "min": None, "max": None}
    return {"median": float(np.median(ok)), "min": float(ok.min()), "max": float(ok.max())}


def config_dict(alg) -> dict:
    from dataclasses import asdict

    return {"name": alg.name, **{k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(alg).items()}}


def summary(problem, network, results: dict, used: dict, tables: dict, spec: dict) -> dict:
    """summary.json: the exact solution, then per algorithm its config, final metrics over seeds,
    divergence, samples and messages."""
    first = next(iter(results.values()))
    m = exact.Moments(problem) if isinstance(problem, Problem) else problem.moments  # a resumed part keeps none
    model = m.model
    out = {
        **problem_fields(problem),
        "network": network.describe(),
        "w_star": first.w_star.tolist(),
        "mspbe_w_star": first.info["mspbe_w_star"],
        "values_exact": exact.value_function(m).tolist() if model else None,
        "config": spec,
        "algorithms": {},
        **({} if model else {"reference": problem.summary()}),  # no model: an estimate, and how precise it is
    }
    for name, r in results.items():
        div = r.info["diverged_at"]
        final = {k: _stats(v[-1]) for k, v in (r.metrics | r.info["counts"]).items() if k != "diverged"}
        out["algorithms"][name] = {
            "config": config_dict(used[name]),
            "run_options": run_options(used[name]),  # with the comparison's other options, `dgtd run` repeats the row
            "tuning": [{"alpha0": a, "score": (s if np.isfinite(s) else None)} for a, s in tables.get(name, [])],
            "final": final,
            # where it converges (over lossy links each method has its own point: docs/links.md), and how far from w*
            "w_fixed": reference(r).tolist(),
            "w_fixed_value_distance": float(exact.value_error(m, reference(r), first.w_star).max()) if model else None,
            "error_tail_averaged": _stats(exact.relative_error(r.w_tail, reference(r)).max(-1)),
            "value_error_area": _stats(error_area(r)),
            "diverged_seeds": [int(b) for b in np.flatnonzero(div >= 0)],
            "diverged_at_step": [int(k) for k in div[div >= 0]],
            "samples_per_step": int(r.info["samples_per_step"]),
            "seconds": r.seconds,
        }
    return out


def agent_errors_npz(results: dict) -> bytes:
    """Every agent's relative error at every checkpoint: arrays NAME/last and NAME/avg (checkpoints, seeds,
    agents or 1), and NAME/steps."""
    arrays = {}
    for name, r in results.items():
        arrays[f"{name}/steps"] = r.steps
        arrays[f"{name}/last"] = r.agent_error_last
        arrays[f"{name}/avg"] = r.agent_error_avg
    return npz_bytes(arrays)


def write_compare(out, problem, network, results: dict, used: dict, tables: dict, spec: dict) -> None:
    """metrics.csv (worst agent per seed), agent_errors.npz (each agent), then summary.json (last); each atomic."""
    write_all(
        out,
        {
            "metrics.csv": lambda: compare_csv(results),
            "bands.csv": lambda: bands_csv(results),
            "agent_errors.npz": lambda: agent_errors_npz(results),
            "summary.json": lambda: json_bytes(summary(problem, network, results, used, tables, spec)),
        },
    )


# A comparison's directory: these files, and while it runs `PARTS/NAME.npz` for each finished algorithm, from which
# the same command, run again after an interrupt, resumes (every algorithm replays the same streams, so a finished
# one's numbers are final).
COMPARE_FILES = ("metrics.csv", "bands.csv", "agent_errors.npz", "summary.json", "compare.png", "consensus.png")
PARTS = "parts"
_ARRAYS = ("steps", "agent_error_last", "agent_error_avg", "w_last", "w_avg", "w_tail", "w_star")


def save_part(out: Path, name: str, result: RunResult, alg, table, record: dict) -> None:
    """One finished algorithm's numbers, its config and tuning, and the comparison's record, as plain arrays."""
    arrays = {k: getattr(result, k) for k in _ARRAYS} | {"w_ref": result.w_ref}
    arrays |= {f"metrics/{k}": v for k, v in result.metrics.items()}
    arrays |= {f"counts/{k}": v for k, v in result.info["counts"].items()}
    arrays |= {
        k: np.asarray(result.info[k]) for k in ("diverged_at", "messages", "bits", "samples_per_step", "mspbe_w_star")
    }
    meta = {
        "record": record,
        "config": config_dict(alg),
        "tuning": [list(t) for t in table],
        "seconds": result.seconds,
        "tail_window": result.tail_window,
    }
    arrays["meta"] = np.asarray(json.dumps(meta))
    atomic_write(Path(out) / PARTS / f"{name}.npz", npz_bytes(arrays))


def load_parts(out: Path, record: dict) -> tuple[dict, dict, dict]:
    """The finished algorithms of an interrupted comparison of the same ``record`` in ``out`` (empty if none)."""
    from dgtd.files import read_npz

    results, used, tables = {}, {}, {}
    paths = [Path(out) / PARTS / f"{name}.npz" for name in record.get("algorithms", ())]
    for path in filter(Path.is_file, paths):  # in the comparison's order, so that the files come out the same
        a = read_npz(
            path,
            "saved part of a comparison",
            f"delete it (or {path.parent}) to run that algorithm again",
            required=(*_ARRAYS, "w_ref", "bits", "meta"),
        )
        meta = json.loads(str(a["meta"]))
        if meta["record"] != record:
            continue
        config = {k: (tuple(v) if isinstance(v, list) else v) for k, v in meta["config"].items() if k != "name"}
        name = meta["config"]["name"]
        used[name] = make_algorithm(name, **config)
        tables[name] = [tuple(t) for t in meta["tuning"]]
        info = {k: a[k] for k in ("diverged_at", "messages", "bits")}
        info |= {
            "samples_per_step": int(a["samples_per_step"]),
            "mspbe_w_star": float(a["mspbe_w_star"]),
            "counts": {k.split("/", 1)[1]: v for k, v in a.items() if k.startswith("counts/")},
        }
        results[name] = RunResult(
            **{k: a[k] for k in _ARRAYS},
            metrics={k.split("/", 1)[1]: v for k, v in a.items() if k.startswith("metrics/")},
            w_trace=None,
            tail_window=int(meta["tail_window"]),
            fixed=FixedPoint(a["w_ref"]),
            final_state={},
            seconds=float(meta["seconds"]),
            info=info,
        )
    return results, used, tables


def prepare_directory(out: Path, record: dict, overwrite: bool) -> tuple[dict, dict, dict]:
    """Refuse a directory that holds another comparison unless ``overwrite``; return the finished algorithms of an
    interrupted run of this one (to resume), else clear the previous comparison's files so that none is stale."""
    out = Path(out)
    if not overwrite:
        refuse_other_results(out, record, "comparison", ignore=("interrupted", "missing"))
    done = ({}, {}, {}) if overwrite else load_parts(out, record)
    if not done[0]:
        shutil.rmtree(out / PARTS, ignore_errors=True)
    for name in COMPARE_FILES:
        (out / name).unlink(missing_ok=True)
    return done


def finish_directory(out: Path) -> None:
    """The comparison's files are complete: the saved parts are no longer needed."""
    shutil.rmtree(Path(out) / PARTS, ignore_errors=True)
