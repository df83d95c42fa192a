"""Time to accuracy: agent-samples each algorithm needs to bring every agent within 10 % and 1 % of w*.

    python benchmarks/time_to_accuracy.py [--tasks baird,boyan,...] [--algorithms dgtd,gtd2,...]
        [--seeds 5] [--iterations T] [--tune] [--out benchmarks/results]

For each task (a named scenario) every algorithm runs on the same sample streams (`dgtd.run.compare`)
with the scenario's step sizes (or tuned ones with --tune). "Samples to x %" is the first checkpoint from
which the median over seeds of the worst agent's relative error |w_i - w*|_inf / |w*|_inf (last iterate)
stays at or below x % until the end of the run, counted in agent-samples (N per step); "messages" is the
number of parameter vectors sent over links by then. Writes time_to_accuracy.md, .json and .png under --out.
"""

from __future__ import annotations

import argparse
import datetime
import json
import time
import warnings
from pathlib import Path

import numpy as np

from dgtd.algorithms import ALGORITHMS
from dgtd.cli.bench import machine
from dgtd.scenarios import get_scenario
from dgtd.run.compare import CompareSettings, compare, configs_for
from dgtd.run.loop import RunSettings

TASKS = ("paper-example-1", "baird", "boyan", "random-mdp", "random-mdp-off", "garnet")
THRESHOLDS = (0.10, 0.01)


def first_stay_below(x: np.ndarray, Y: np.ndarray, threshold: float):
    """x at the first checkpoint from which the median over seeds of Y (checkpoints, seeds) stays <= threshold."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        med = np.where(np.isfinite(Y).sum(axis=1) * 2 > Y.shape[1], np.nanmedian(Y, axis=1), np.inf)
    ok = med <= threshold
    bad = np.flatnonzero(~ok)
    first = 0 if bad.size == 0 else bad[-1] + 1
    return None if first >= len(ok) else float(np.nanmedian(x[first]))


def task_rows(task: str, algorithms, seeds: int, iterations: int | None, tune: bool, backend: str):
    sc = get_scenario(task)
    T = int(iterations or sc.iterations)
    cs = CompareSettings(tuple(algorithms), RunSettings(iterations=T, seeds=seeds, checkpoints=200, backend=backend),
                         tune=tune)
    t = time.perf_counter()
    results, used, _ = compare(sc.problem, sc.network, sc.sampling, configs_for(sc, cs.algorithms), cs,
                               source_factory=sc.source)
    wall = time.perf_counter() - t
    rows = []
    for name, r in results.items():
        div = r.info["diverged_at"]
        err = r.metrics["error_last"]
        row = {"task": task, "algorithm": name, "alpha0": used[name].alpha0, "iterations": T, "seeds": seeds,
               "agents": sc.problem.n_agents, "samples_budget": T * sc.problem.n_agents,
               "diverged_seeds": int(np.sum(div >= 0)), "first_divergence_step": int(div[div >= 0].min()) if np.any(div >= 0) else None,
               "final_error_median": float(np.nanmedian(err[-1])) if np.isfinite(err[-1]).any() else None,
               "seconds": r.seconds}
        for th in THRESHOLDS:
            key = f"{th:.0%}"
            row[f"samples_to_{key}"] = first_stay_below(r.info["counts"]["samples"], err, th)
            row[f"messages_to_{key}"] = first_stay_below(r.info["counts"]["messages"], err, th)
        rows.append(row)
        print(f"{task:<16}{name:<15}" + "".join(f"{_fmt(row, f'samples_to_{th:.0%}'):>22}" for th in THRESHOLDS), flush=True)
    print(f"{task}: {wall:.1f} s for {len(results)} algorithms x {seeds} seeds x {T:,} iterations", flush=True)
    return rows


def _fmt(row: dict, key: str) -> str:
    v = row[key]
    if v is not None:
        return f"{v:.3g}"
    if row["diverged_seeds"] * 2 > row["seeds"]:
        return f"diverged (step {row['first_divergence_step']:,})"
    return f"> {row['samples_budget']:.3g}" if key.startswith("samples") else "-"


def markdown(rows: list, header: str) -> str:
    lines = [header, "",
             "| task | algorithm | alpha0 | samples to 10 % | samples to 1 % | messages to 1 % | final error (median) |",
             "|---|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        fe = "diverged" if r["final_error_median"] is None else f"{r['final_error_median']:.3g}"
        lines.append(f"| {r['task']} | {r['algorithm']} | {r['alpha0']:g} | {_fmt(r, 'samples_to_10%')} | "
                     f"{_fmt(r, 'samples_to_1%')} | {_fmt(r, 'messages_to_1%')} | {fe} |")
    return "\n".join(lines) + "\n"


def plot(rows: list, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tasks = list(dict.fromkeys(r["task"] for r in rows))
    cols = min(3, len(tasks))
    nrow = (len(tasks) + cols - 1) // cols
    fig, axes = plt.subplots(nrow, cols, figsize=(5.2 * cols, 3.4 * nrow), squeeze=False)
    for ax, task in zip(axes.ravel(), tasks):
        rs = [r for r in rows if r["task"] == task]
        y = np.arange(len(rs))
        budget = rs[0]["samples_budget"]
        for off, th, color in ((-0.2, "10%", "#9ecae1"), (0.2, "1%", "#08519c")):
            vals = [r[f"samples_to_{th}"] for r in rs]
            ax.barh(y + off, [v if v is not None else 0 for v in vals], height=0.38, color=color, label=f"to {th}")
            for yi, v, r in zip(y, vals, rs):
                if v is None:
                    txt = "diverged" if r["diverged_seeds"] * 2 > r["seeds"] else "not reached"
                    ax.text(1.5, yi + off, txt, va="center", fontsize=6.5, color="#444")
        ax.axvline(budget, color="k", ls=":", lw=1, label="budget")
        ax.set_xscale("log")
        ax.set_xlim(1, budget * 3)
        ax.set_yticks(y, [r["algorithm"] for r in rs], fontsize=8)
        ax.invert_yaxis()
        ax.set_title(task, fontsize=9)
        ax.set_xlabel("agent-samples (median over seeds)", fontsize=8)
        ax.grid(alpha=0.3, axis="x", which="both")
    for ax in axes.ravel()[len(tasks):]:
        ax.axis("off")
    axes.ravel()[0].legend(fontsize=7, loc="lower right")
    fig.suptitle("samples until every agent stays within 10 % / 1 % of w* (last iterate)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tasks", default=",".join(TASKS))
    ap.add_argument("--algorithms", default=",".join(ALGORITHMS))
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--iterations", type=int, default=None, help="override every task's iterations")
    ap.add_argument("--tune", action="store_true", help="tune each algorithm's alpha0 first (dgtd compare --tune)")
    ap.add_argument("--backend", default="numba", choices=("numba", "numpy"))
    ap.add_argument("--out", default="benchmarks/results")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    rows = []
    for task in args.tasks.split(","):
        rows += task_rows(task.strip(), args.algorithms.split(","), args.seeds, args.iterations, args.tune, args.backend)
    total = time.perf_counter() - t0
    header = (f"Measured {datetime.date.today().isoformat()} on {machine()}; {args.seeds} seeds per algorithm, "
              f"{'tuned' if args.tune else 'scenario'} step sizes, {args.backend} backend; whole benchmark {total:.0f} s.")
    (out / "time_to_accuracy.md").write_text(markdown(rows, header))
    (out / "time_to_accuracy.json").write_text(json.dumps({"machine": machine(), "seconds": total, "rows": rows}, indent=2))
    plot(rows, out / "time_to_accuracy.png")
    print(markdown(rows, header))
    print(f"wrote {out}/time_to_accuracy.md, .json, .png")


if __name__ == "__main__":
    main()
