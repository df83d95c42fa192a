"""Results on disk: summary.json, metrics.csv and arrays, each written atomically (temporary file, then rename)."""

from __future__ import annotations

import csv
import io
import time
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from dgtd.errors import DgtdInputError
from dgtd.files import read_json
from dgtd.problems import exact
from dgtd.run.atomic import atomic_write, atomic_write_json, file_mode, json_bytes, json_ready  # noqa: F401
from dgtd.run.loop import RunResult


def first_difference(a: dict, b: dict) -> str:
    """The first key (in sorted order) where two configs differ, as 'key = A there, B here'; '' if none."""
    for key in sorted(set(a) | set(b)):
        if a.get(key) != b.get(key):
            return f"{key} = {a.get(key)!r} there, {b.get(key)!r} here"
    return ""


def saved_config(summary: Path) -> dict:
    """The config a finished run's summary.json records ({} where there is none, or it cannot be read)."""
    try:
        config = read_json(summary, "results file", "").get("config", {})
    except (DgtdInputError, OSError):
        return {}
    return dict(config) if isinstance(config, dict) else {}


def refuse_other_results(out: Path, record: dict, what: str, ignore=()) -> None:
    """A one-line refusal unless ``out`` holds no summary.json, a damaged one (nothing readable to protect), or the
    results of this very config ``record`` (keys in ``ignore`` aside): a directory never mixes two runs."""
    summary = Path(out) / "summary.json"
    if not summary.is_file():
        return
    saved = {k: v for k, v in saved_config(summary).items() if k not in ignore}
    diff = first_difference(saved, record) if saved else ""
    if diff:
        raise DgtdInputError(
            f"{out} holds the results of another {what} ({diff}); choose another --out, or pass "
            "--overwrite to replace them"
        )


def reference(result: RunResult) -> np.ndarray:
    """What a run's errors are measured against (`RunResult.w_ref`): the algorithm's fixed point, w* for every agent
    unless it converges elsewhere (DGTD with rho > 0)."""
    return result.w_ref


def held_reference(result: RunResult) -> np.ndarray:
    """The reference rows of the agents whose rows ``result`` holds (`reference`'s, cut to a rank's agents where
    the rows stay on their ranks: `RunResult.rows`)."""
    ref = reference(result)
    return ref if result.rows is None else result.rows.rows(ref)


def n_agents(result: RunResult) -> int:
    """The run's agents, however many of their rows ``result`` holds (older results and stand-ins: its rows')."""
    return int(result.info.get("n_agents") or result.w_last.shape[1])


def over_agents(result: RunResult, x: np.ndarray) -> np.ndarray:
    """The largest value of x (..., n) over every agent of the run (its last axis), however the rows are held: the
    ranks combined where each holds its own."""
    m = np.asarray(np.max(x, axis=-1), dtype=np.float64)
    return m if result.rows is None else result.rows.max(np.atleast_1d(m)).reshape(m.shape)


def consensus_of(result: RunResult, W: np.ndarray) -> np.ndarray:
    """The consensus error (B,) of every agent's W (B, n, q) (`dgtd.problems.exact.consensus_error`), up the
    agents' fixed tree across the ranks where the rows stay on them."""
    return exact.consensus_error(W) if result.rows is None else result.rows.consensus(W)


def plain(report: dict) -> dict:
    """An algorithm's report (`RunResult.report`) as JSON-ready data: arrays as nested lists."""
    return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in report.items()}


def metrics_rows(result: RunResult, algorithm: str):
    """Long format: (algorithm, seed, step, metric, value), one row per checkpoint, seed and metric."""
    for name, values in result.metrics.items():
        for c, step in enumerate(result.steps):
            for b in range(values.shape[1]):
                yield algorithm, b, int(step), name, float(values[c, b])


BAND = (5.0, 95.0)  # percentiles over seeds in bands.csv: a 90 % band, as the figures draw


def bands_csv(results: dict) -> bytes:
    """Long format over seeds: algorithm, step, metric, median, q05, q95 (the 90 % band, linear interpolation between
    seeds) and seeds (how many are finite there: diverged seeds are NaN), for every checkpoint and metric."""
    import warnings

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["algorithm", "step", "metric", "median", "q05", "q95", "seeds"])
    for name, result in results.items():
        for metric, Y in result.metrics.items():
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # a checkpoint where every seed is NaN
                med = np.nanmedian(Y, axis=1)
                lo, hi = np.nanpercentile(Y, BAND, axis=1)
            alive = np.isfinite(Y).sum(axis=1)
            w.writerows(
                [name, int(k), metric, float(m), float(a), float(b), int(n)]
                for k, m, a, b, n in zip(result.steps, med, lo, hi, alive)
            )
    return buf.getvalue().encode()


class MeasuredSoFar:
    """metrics.csv of the checkpoints measured so far, kept as a run goes (`dgtd.run.loop.run`'s ``on_measured``):
    rewritten whole and atomically, at most a tenth of the time (the next write waits nine times the last one's
    duration: a run of many seeds and checkpoints is not slowed by it), and at once by ``write()`` (on Ctrl-C)."""

    def __init__(self, out: Path, algorithm: str, csv_of=None):
        self.out, self.algorithm = Path(out), algorithm
        self.csv_of = csv_of or (lambda latest: metrics_csv(latest, algorithm))  # a learning run's: its own writer
        self.latest: Any = None
        self.next_at = 0.0

    def __call__(self, steps: np.ndarray, metrics: dict) -> None:
        self.latest = SimpleNamespace(steps=steps, metrics=metrics)
        if time.perf_counter() >= self.next_at:
            self.write()

    def write(self) -> None:
        if self.latest is None:
            return
        started = time.perf_counter()
        atomic_write(self.out / "metrics.csv", self.csv_of(self.latest))
        self.next_at = time.perf_counter() + 9.0 * (time.perf_counter() - started)


def metrics_csv(result: RunResult, algorithm: str) -> bytes:
    return rows_csv(metrics_rows(result, algorithm))


def rows_csv(rows, column: str = "algorithm", step: str = "step") -> bytes:
    """metrics.csv of long-format ``rows`` (label, seed, step, metric, value), a run's or a learning run's (the
    label's column named ``column``, the step's ``step``: a networked run's are episodes): the one writer of every
    metrics.csv."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow([column, "seed", step, "metric", "value"])
    w.writerows(rows)
    return buf.getvalue().encode()


def problem_fields(problem) -> dict:
    """What results files say of the problem: its name, sizes, discount, whether it is off-policy, and for an
    episodic model whether its restarts are samples (`dgtd.problems.model.Problem.restarts`)."""
    fields = {
        "problem": problem.name,
        "n_states": problem.n_states,
        "n_agents": problem.n_agents,
        "n_features": problem.n_features,
        "gamma": problem.gamma,
        "off_policy": problem.off_policy,
    }
    if getattr(problem, "terminal", None) is not None and hasattr(problem, "restarts"):
        fields["restarts"] = problem.restarts
    return fields


INLINE_NUMBERS = 1_000_000  # per-agent numbers summary.json holds itself; beyond, agents.npz holds them (`summary`)
AGENTS_FILE = "agents.npz"
TRACES = ("agent_error_last", "agent_error_avg")  # trajectory.npz's per-agent arrays (C, B, N): agents on axis 2


def per_agent(result: RunResult) -> dict:
    """Every per-agent array of a run's results (name -> array, agents on the axis after the seeds', or first where
    there is no seeds axis) of the agents it holds: the last, averaged and tail-averaged iterates, their errors
    (relative, value, to the true values where there is a model, projected Bellman), what each agent sent that
    arrived, and what the algorithm reports per agent (DGTD's theta*, mu*)."""
    moments, whole, ref = result.info["moments"], reference(result), held_reference(result)
    outputs = (("last", result.w_last), ("avg", result.w_avg), ("tail", result.w_tail))
    arrays = {f"w_{k}": np.asarray(W) for k, W in outputs}
    arrays |= {f"error_{k}": exact.relative_error(W, ref, of=whole) for k, W in outputs}
    arrays |= {f"value_error_{k}": exact.value_error(moments, W, ref, of=whole) for k, W in outputs}
    if moments.model:
        arrays |= {f"true_value_error_{k}": exact.true_value_error(moments, W) for k, W in outputs}
    arrays["rmspbe_tail"] = exact.rmspbe(moments, result.w_tail)
    arrays |= {f"{k}_per_agent": v.mean(axis=0) for k, v in result.info.get("per_agent", {}).items()}
    N = n_agents(result)
    report = {k: v for k, v in result.report.items() if isinstance(v, np.ndarray) and v.ndim and v.shape[0] == N > 1}
    held = report if result.rows is None else {k: result.rows.rows(v) for k, v in report.items()}
    return arrays | held


def agent_axes(agents: dict) -> dict:
    """Each per-agent array's agent axis (`per_agent`'s, then trajectory.npz's `TRACES`): after the seeds', or first
    where it has none (what the algorithm reports per agent, the counts averaged over seeds)."""
    first = {k for k in agents if k.endswith("_per_agent") or not (k.startswith(("w_", "rmspbe")) or "error_" in k)}
    return {k: 0 if k in first else 1 for k in agents} | dict.fromkeys(TRACES, 2)


def agent_files(result: RunResult) -> list[str]:
    """The files of the agents' rows where each rank writes its own (`RunResult.rows`): rank 0's agents.npz, rank
    r's agents.r.npz, each with ``agent``, the ids of its rows."""
    return [AGENTS_FILE, *(f"agents.{r}.npz" for r in range(1, result.rows.n_ranks))]


def _per_agent_numbers(result: RunResult, agents: dict) -> int:
    """How many per-agent numbers the run's results hold, over every rank where the rows stay on them."""
    n = np.array([sum(a.size for a in agents.values())], np.int64)
    return int((n if result.rows is None else result.rows.total(n))[0])


def summary(result: RunResult, config: dict, agents: dict | None = None) -> dict:
    """What summary.json holds: the exact solution, each seed's and agent's estimates and errors (`per_agent`; where
    they pass `INLINE_NUMBERS` numbers, agents.npz holds them and ``per_agent`` names it: a million agents' rows as
    JSON took minutes; where they stay on their ranks, each rank's file: `agent_files`), the worst of each over seeds
    and agents, the config. Where the rows stay on their ranks, every rank computes it (the ranks combine the worst
    and the consensus), rank 0 writes it."""
    moments = result.info["moments"]
    agents = per_agent(result) if agents is None else agents
    inline = result.rows is None and _per_agent_numbers(result, agents) <= INLINE_NUMBERS
    errors = [name for name in agents if "error_" in name and "true" not in name]
    largest = over_agents(result, np.array([np.max(agents[name]) for name in errors])[:, None])
    worst = {f"max_{name}": float(x) for name, x in zip(errors, largest, strict=True)}  # (one collective, spread)
    if inline:
        rows = {k: v.tolist() for k, v in agents.items()}
    else:
        rows = {"per_agent": {"file": AGENTS_FILE, "arrays": sorted(agents)}}
        if result.rows is not None:  # each rank's file, with its agents' traces (`write_results`)
            rows["per_agent"] |= {"parts": agent_files(result), "axes": agent_axes(agents)}
            rows["per_agent"]["arrays"] = sorted([*agents, *TRACES])
    return {
        "w_star": result.w_star.tolist(),
        "w_reference": reference(result).tolist(),
        # where the run converges (its channel and its mixing: `dgtd.problems.exact.weighted_w_star`), and how far
        # that is from w* in the d-weighted value error
        "w_fixed": result.fixed.w.tolist(),
        "w_fixed_value_distance": float(exact.value_error(moments, result.fixed.w, result.w_star).max())
        if moments.model
        else None,
        "regularisation_shift": result.info.get("regularisation_shift", 0.0),
        # what the algorithm says of its fixed point and its run (DGTD: theta*, mu*, boxes, KKT)
        **plain({k: v for k, v in result.report.items() if k not in agents}),
        "mspbe_w_star": result.info["mspbe_w_star"],
        **rows,
        "tail_window": result.tail_window,
        **worst,
        # no model: the reference is estimated, and says how well
        **(
            {"true_value_error_w_star": float(exact.true_value_error(moments, result.w_star[None])[0])}
            if moments.model
            else {"reference": moments.problem.summary()}
        ),
        "consensus_last": consensus_of(result, result.w_last).tolist(),
        "messages": result.info["messages"].tolist(),
        "bits": result.info["bits"].tolist(),
        **({"message_ages": age_summary(result.info["message_ages"])} if "message_ages" in result.info else {}),
        "stationary_distribution": None if result.info["d"] is None else result.info["d"].tolist(),
        "seconds": result.seconds,
        "config": config,
    }


def age_summary(ages: dict) -> dict:
    """What an asynchronous run's ranks counted of the messages they used (`dgtd.backends.mpi.message_ages`): the
    ages in steps (0: the step's own message, as a synchronous run uses; k: k steps old), each ghost counted once a
    step, and the seconds a message took to arrive."""
    counts = np.asarray(ages["counts"])
    age = np.arange(len(counts))
    used = int(counts.sum())
    share = np.cumsum(counts) / max(used, 1)
    quantile = lambda p: int(age[np.searchsorted(share, p)]) if used else None  # noqa: E731
    seen = np.flatnonzero(counts)
    received, seconds, largest = (float(x) for x in ages["transit"])
    return {
        "used": used,
        "mean": float(counts @ age / used) if used else None,
        "median": quantile(0.5),
        "p95": quantile(0.95),
        "max": int(age[seen[-1]]) if used else None,
        "steps": {str(int(age[i])): int(counts[i]) for i in seen},
        "messages_received": int(received),
        "transit_seconds_mean": seconds / received if received else None,
        "transit_seconds_max": largest,
    }


def ages_csv(ages: dict) -> bytes:
    """message_ages.csv: age_steps,count (the ages that occurred; `age_summary`)."""
    steps = age_summary(ages)["steps"]
    return ("age_steps,count\n" + "".join(f"{a},{n}\n" for a, n in steps.items())).encode()


def write_results(
    out: Path, result: RunResult, config: dict, algorithm: str, extra: dict | None = None, also: dict | None = None
) -> list[str]:
    """summary.json, metrics.csv (per seed), bands.csv (median and 90 % band over seeds) and trajectory.npz in
    ``out``; summary.json is written last. Where the rows stay on their ranks (`RunResult.rows`), every rank calls
    it: each writes its agents' file (`agent_files`), then rank 0 the others.

    ``extra``: scenario-specific numbers, stored in summary.json under "scenario"; ``also``: more files (name ->
    a function returning its bytes), written with the others, before summary.json. Returns the names written (none
    on a rank other than 0).
    """
    out = Path(out)
    agents = per_agent(result)
    spread = result.rows is not None
    arrays = {"steps": result.steps} | ({} if spread else {k: getattr(result, k) for k in TRACES})
    if result.w_trace is not None:
        arrays["w_trace"] = result.w_trace
    ages = result.info.get("message_ages")  # an asynchronous run's (`age_summary`)
    failed = _write_own_agents(out, result, agents) if spread else {}
    content = summary(result, config, agents) | ({"scenario": extra} if extra else {})  # (a collective, spread)
    if spread and not result.rows.root:
        return []
    outside = not spread and _per_agent_numbers(result, agents) > INLINE_NUMBERS
    files = {
        "metrics.csv": lambda: metrics_csv(result, algorithm),
        "bands.csv": lambda: bands_csv({algorithm: result}),
        "trajectory.npz": lambda: npz_bytes(arrays),
        **({"message_ages.csv": lambda: ages_csv(ages)} if ages is not None else {}),
        **({AGENTS_FILE: lambda: npz_bytes(agents)} if outside else {}),
        **(also or {}),
        "summary.json": lambda: json_bytes(content),
    }
    if failed:  # summary.json would name files that are not there
        failed["summary.json"] = "not written: the agents' files are incomplete"
        files.pop("summary.json")
    parts = agent_files(result) if spread else []
    try:
        write_all(out, files)
    except NotWritten as e:
        failed |= e.failed
    if failed:
        raise NotWritten(out, failed, [n for n in [*parts, *files] if n not in failed])
    return [*parts, *files]


def _write_own_agents(out: Path, result: RunResult, agents: dict) -> dict:
    """This rank's agents' rows (and trajectory.npz's per-agent traces of them) in its file (`agent_files`), then
    which files failed on any rank, on rank 0 ({name: reason}; {} on the others: rank 0 says it)."""
    name = agent_files(result)[result.rows.rank]
    rows = agents | {k: getattr(result, k) for k in TRACES} | {"agent": np.asarray(result.rows.agents, np.int64)}
    try:
        atomic_write(out / name, npz_bytes(rows))
        reason = None
    except OSError as e:
        reason = e.strerror or str(e)
    every = result.rows.collect((name, reason))
    return {} if every is None else {n: r for n, r in every if r is not None}


def npz_bytes(arrays: dict) -> bytes:
    """A compressed .npz of ``arrays``, as a file holds it."""
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    return buf.getvalue()


class NotWritten(OSError):
    """Files of a results directory that could not be written (a full disk, a lost mount): the others are complete,
    and none is left half-written."""

    def __init__(self, out: Path, failed: dict, written: list):
        reason = next(iter(failed.values()))
        kept = f"; {', '.join(written)} {'is' if len(written) == 1 else 'are'} complete there" if written else ""
        super().__init__(f"could not write {', '.join(failed)} in {out} ({reason}){kept}")
        self.failed, self.written = failed, written


def write_all(out: Path, files: dict) -> None:
    """Write each file of ``files`` (name -> a function returning its bytes) atomically, in order; one that cannot be
    written does not stop the next (a smaller one may still fit); then `NotWritten` names those that failed."""
    failed, written = {}, []
    for name, content in files.items():
        try:
            atomic_write(Path(out) / name, content())
            written.append(name)
        except OSError as e:
            failed[name] = e.strerror or str(e)
    if failed:
        raise NotWritten(Path(out), failed, written)


def pinned_to_boxes(result: RunResult, share: float = 0.5) -> dict:
    """Variable -> the fraction of its last iterate's components (all seeds and agents) that sit on their
    projection box, for the variables where that is at least ``share``: a sign that the step size is too large
    (the iterates jump from box to box) or that a box the user set excludes the solution."""
    out = {}
    for name, bound in result.report.get("boxes", {}).items():
        x = np.asarray(result.final_state.get(name))
        if x.size == 0 or not np.isfinite(bound) or bound == 0:
            continue
        finite = x[np.isfinite(x)]
        counts = np.array([np.sum(np.abs(finite) >= bound * (1 - 1e-12)), finite.size], np.int64)
        pinned, n = counts if result.rows is None else result.rows.total(counts)
        frac = float(pinned / n) if n else 0.0
        if frac >= share:
            out[name] = frac
    return out


@dataclass(frozen=True)
class Results:
    """A results directory as written by `dgtd run` (`write_results`): ``summary`` (summary.json), ``metrics``
    (metrics.csv, a column name -> array mapping) and ``trajectory`` (trajectory.npz's arrays, empty if absent)."""

    summary: dict
    metrics: dict
    trajectory: dict

    def series(self, metric: str, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """(the checkpoints' steps, the values) of one metric of metrics.csv (its long rows: seed, step, metric,
        value) for one seed; a `DgtdInputError` naming the metrics there are where it has none such."""
        names = np.asarray(self.metrics["metric"])
        rows = (names == metric) & (np.asarray(self.metrics["seed"]) == seed)
        if not rows.any():
            raise DgtdInputError(
                f"no metric {metric!r} of seed {seed} in these results; they hold {', '.join(dict.fromkeys(names))}"
            )
        return np.asarray(self.metrics["step"])[rows], np.asarray(self.metrics["value"])[rows]


def read_results(out) -> Results:
    """The results of a run directory, or a `DgtdInputError` saying which file is missing or damaged.

    Example, after ``dgtd run paper-example-1``::

        results = dgtd.read_results("runs/paper-example-1")
        steps, error = results.series("error_avg")  # seed 0's averaged iterates' worst relative error
        error[-1], results.summary["w_star"]
    """
    from dgtd.files import numbers, read_csv, read_json, read_npz

    out = Path(out)
    fix = "run it again"
    summary = read_json(out / "summary.json", "results file", fix)
    rows = read_csv(out / "metrics.csv", "results file", fix, required=("seed", "step", "metric", "value"))
    metrics = {
        "seed": numbers(rows, "seed", int, out / "metrics.csv", "results file", fix),
        "step": numbers(rows, "step", int, out / "metrics.csv", "results file", fix),
        "metric": [r["metric"] for r in rows],
        "value": numbers(rows, "value", float, out / "metrics.csv", "results file", fix),
    }
    trajectory = read_npz(out / "trajectory.npz", "results file", fix) if (out / "trajectory.npz").exists() else {}
    summary, trajectory = with_agents(out, summary, trajectory, fix)
    return Results(summary, metrics, trajectory)


def with_agents(out: Path, summary: dict, trajectory: dict, fix: str) -> tuple[dict, dict]:
    """summary.json's and trajectory.npz's contents with the agents' rows that many agents' results keep outside
    them (summary.json's ``per_agent``: agents.npz, or each rank's file) read back in: the per-agent arrays into the
    summary, the per-agent traces (`TRACES`) into the trajectory."""
    if "per_agent" not in summary:
        return summary, trajectory
    rows = read_agents(out, summary["per_agent"], fix)
    return summary | {k: v for k, v in rows.items() if k not in TRACES}, trajectory | {
        k: v for k, v in rows.items() if k in TRACES
    }


def read_agents(out: Path, per_agent: dict, fix: str) -> dict:
    """The agents' rows a results directory holds outside summary.json (its ``per_agent`` entry): agents.npz, or
    where each rank wrote its own agents' file (``parts``), every file's rows put together in the agents' order."""
    from dgtd.files import read_npz

    if "parts" not in per_agent:
        return read_npz(Path(out) / per_agent["file"], "results file", fix)
    parts = [read_npz(Path(out) / name, "results file", fix) for name in per_agent["parts"]]
    order = np.argsort(np.concatenate([p["agent"] for p in parts]), kind="stable")
    axes = per_agent["axes"]
    return {
        name: np.take(np.concatenate([p[name] for p in parts], axis=axes[name]), order, axis=axes[name])
        for name in per_agent["arrays"]
    }
