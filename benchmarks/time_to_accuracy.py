"""Time to accuracy: agent-samples and messages until every agent's value error stays below 10 % and 1 %.

    python benchmarks/time_to_accuracy.py            # every task, tuned step sizes, writes the docs too
    python benchmarks/time_to_accuracy.py --tasks boyan,garnet --seeds 4 --out /tmp/tta --no-docs

For each task (a named scenario) every algorithm runs on the same sample streams (`dgtd.run.compare`).

- **Error**: the worst agent's value error |Phi (w_i - w*)|_d / |Phi w*|_d (`dgtd.problems.exact.value_error`,
  the d-weighted RMSVE relative to the size of the values), of the algorithm's output.
- **Output**: each method's better of its last iterate and its tail average (the mean over the last half of the
  steps so far, `dgtd.run.loop.tail_at`), chosen on the tuning seeds and named in the table.
- **Step sizes**: alpha0 from the method's comparison default x (1/10, 1/3, 1, 3, 10), chosen with the output on
  TUNE_SEEDS seeds of base seed + 1,000,003, streams independent of the reported ones: the fewest samples to 1 %,
  then to 10 %, then the smallest final error. The schedule and offset are the method's own (DGTD's defaults:
  alpha0 / sqrt(k + 1000), kappa 3; the baselines: alpha0 / sqrt(k + beta) with the scenario's beta).
- **Samples to x %**, per seed: the first checkpoint from which that seed's error stays at or below x % until the
  end of the run, in agent-samples (N per step: every method, centralised or not, consumes the N agents'
  transitions at each step); the table gives the median over the reported seeds and the 5th-95th percentile band
  ("> B": not reached within the budget B by half the seeds or more). **Messages**: parameter vectors sent over
  links by then.

Writes time_to_accuracy.md, .json and .png under --out, and, unless --no-docs, the table and the figure into
docs/benchmarks.md (between its markers) and docs/time_to_accuracy.png.
"""

from __future__ import annotations

import argparse
import datetime
import json
import re
import shutil
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from dgtd.algorithms import ALGORITHMS
from dgtd.cli.bench import machine
from dgtd.run.compare import TUNE_GRID, TUNE_SEED_OFFSET, CompareSettings, compare, configs_for
from dgtd.run.loop import RunSettings, run
from dgtd.scenarios import get_scenario

# Task -> agent-steps budget (iterations): sized so that at least three methods reach 10 % on every task.
TASKS = {
    "paper-example-1": 400_000,
    "baird": 4_000_000,
    "boyan": 100_000,
    "random-mdp": 100_000,
    "random-mdp-off": 100_000,
    "garnet": 100_000,
    "random-walk": 100_000,
}
THRESHOLDS = (0.10, 0.01)
OUTPUTS = ("last", "tail")
TUNE_SEEDS = 3
DOCS = Path(__file__).resolve().parents[1] / "docs"
BEGIN, END = "<!-- time-to-accuracy: begin -->", "<!-- time-to-accuracy: end -->"


def first_stay_below(x: np.ndarray, Y: np.ndarray, threshold: float) -> np.ndarray:
    """Per seed: x at the first checkpoint from which Y (checkpoints, seeds) stays <= threshold; inf if never."""
    ok = np.nan_to_num(Y, nan=np.inf) <= threshold
    out = np.full(Y.shape[1], np.inf)
    for b in range(Y.shape[1]):
        bad = np.flatnonzero(~ok[:, b])
        first = 0 if bad.size == 0 else bad[-1] + 1
        if first < len(ok):
            out[b] = x[first, b] if x.ndim == 2 else x[first]
    return out


def band(values: np.ndarray) -> tuple[float, float, float]:
    """(median, 5th, 95th percentile) over seeds; inf where half the seeds or more never got there."""
    v = np.sort(values)
    med = float(np.median(v)) if np.isfinite(v).sum() * 2 > len(v) else float("inf")
    with np.errstate(invalid="ignore"):  # interpolating towards a seed that never got there: inf
        lo, hi = (float(np.nan_to_num(np.percentile(v, p), nan=np.inf)) for p in (5, 95))
    return med, lo, hi


def score(result, output: str) -> tuple:
    """The tuning criterion: (median samples to 1 %, to 10 %, final median error); smaller is better."""
    Y = result.metrics[f"value_error_{output}"]
    x = result.info["counts"]["samples"]
    final = np.nanmedian(Y[-1]) if np.isfinite(Y[-1]).any() else np.inf
    return (*(band(first_stay_below(x, Y, th))[0] for th in reversed(THRESHOLDS)), float(final))


def tune(sc, name, config, settings):
    """(config, output) with the best `score` over alpha0 x TUNE_GRID and OUTPUTS, on the tuning seeds."""
    tune_settings = replace(settings, seeds=TUNE_SEEDS, seed=settings.seed + TUNE_SEED_OFFSET)
    best = None
    for factor in TUNE_GRID:
        cand = replace(config, alpha0=float(config.alpha0 * factor))
        source = None if sc.source is None else sc.source(tune_settings.seed, range(tune_settings.seeds))
        r = run(sc.problem, sc.network, cand, sc.sampling, tune_settings, source=source)
        for output in OUTPUTS:
            s = score(r, output)
            if best is None or s < best[0]:
                best = (s, cand, output)
    return best[1], best[2]


def task_rows(task: str, algorithms, seeds: int, iterations: int | None, backend: str):
    sc = get_scenario(task)
    T = int(iterations or TASKS.get(task, sc.iterations))
    settings = RunSettings(iterations=T, seeds=seeds, checkpoints=200, backend=backend)
    t = time.perf_counter()
    configs, outputs = {}, {}
    for name, config in configs_for(sc, algorithms).items():
        configs[name], outputs[name] = tune(sc, name, config, settings)
    cs = CompareSettings(tuple(algorithms), settings)
    results, used, _ = compare(sc.problem, sc.network, sc.sampling, configs, cs, source_factory=sc.source)
    wall = time.perf_counter() - t
    rows = []
    for name, r in results.items():
        out = outputs[name]
        Y = r.metrics[f"value_error_{out}"]
        div = r.info["diverged_at"]
        row = {
            "task": task,
            "algorithm": name,
            "output": out,
            "alpha0": used[name].alpha0,
            "schedule": steps_text(used[name]),
            "iterations": T,
            "seeds": seeds,
            "agents": sc.problem.n_agents,
            "samples_budget": T * sc.problem.n_agents,
            "diverged_seeds": int(np.sum(div >= 0)),
            "final_error": band(np.nan_to_num(Y[-1], nan=np.inf)),
            "seconds": r.seconds,
        }
        for th in THRESHOLDS:
            key = f"{th:.0%}"
            row[f"samples_to_{key}"] = band(first_stay_below(r.info["counts"]["samples"], Y, th))
            row[f"messages_to_{key}"] = band(first_stay_below(r.info["counts"]["messages"], Y, th))
        rows.append(row)
        print(
            f"{task:<16}{name:<15}{out:<6}" + "".join(f"{_fmt(row, f'samples_to_{th:.0%}'):>34}" for th in THRESHOLDS),
            flush=True,
        )
    print(
        f"{task}: {wall:.1f} s (tuning and runs) for {len(results)} algorithms x {seeds} seeds x {T:,} iterations",
        flush=True,
    )
    return rows


def steps_text(config) -> str:
    """alpha_k as a formula: alpha0/sqrt(k+beta), alpha0/(k+beta) or the constant alpha0."""
    a, b = f"{config.alpha0:.3g}", f"{config.beta:g}"
    return {"sqrt": f"{a}/sqrt(k+{b})", "harmonic": f"{a}/(k+{b})"}.get(config.schedule, f"{a} (constant)")


def _num(x: float) -> str:
    return f"{x:.2g}" if np.isfinite(x) else "inf"


def _fmt(row: dict, key: str) -> str:
    med, lo, hi = row[key]
    if np.isfinite(med):
        return f"{_num(med)} [{_num(lo)}, {_num(hi)}]"
    if row["diverged_seeds"] * 2 > row["seeds"]:
        return "diverged"
    return f"> {row['samples_budget']:.2g}" if key.startswith("samples") else "-"


def reached(rows: list, task: str, threshold: str = "10%") -> list[str]:
    return [r["algorithm"] for r in rows if r["task"] == task and np.isfinite(r[f"samples_to_{threshold}"][0])]


def markdown(rows: list, header: str) -> str:
    lines = [
        header,
        "",
        "| task | algorithm | output | step sizes | samples to 10 % | samples to 1 % | messages to 1 % | final error |",
        "|---|---|---|---|---:|---:|---:|---:|",
    ]
    for r in rows:
        fe = r["final_error"]
        final = "diverged" if r["diverged_seeds"] * 2 > r["seeds"] else f"{fe[0]:.2%}" if np.isfinite(fe[0]) else "n/a"
        lines.append(
            f"| {r['task']} | {r['algorithm']} | {r['output']} | {r['schedule']} | "
            f"{_fmt(r, 'samples_to_10%')} | {_fmt(r, 'samples_to_1%')} | {_fmt(r, 'messages_to_1%')} | "
            f"{final} |"
        )
    tasks = list(dict.fromkeys(r["task"] for r in rows))
    lines += [
        "",
        "Methods reaching 10 % (median over seeds) within the budget: "
        + "; ".join(f"{t} {len(reached(rows, t))}" for t in tasks)
        + ".",
    ]
    return "\n".join(lines) + "\n"


def plot(rows: list, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tasks = list(dict.fromkeys(r["task"] for r in rows))
    cols = min(3, len(tasks))
    nrow = (len(tasks) + cols - 1) // cols
    fig, axes = plt.subplots(nrow, cols, figsize=(5.4 * cols, 3.6 * nrow), squeeze=False)
    for ax, task in zip(axes.ravel(), tasks):
        rs = [r for r in rows if r["task"] == task]
        y = np.arange(len(rs))
        budget = rs[0]["samples_budget"]
        for off, th, color in ((-0.2, "10%", "#9ecae1"), (0.2, "1%", "#08519c")):
            med = np.array([r[f"samples_to_{th}"][0] for r in rs])
            lo = np.array([r[f"samples_to_{th}"][1] for r in rs])
            hi = np.array([r[f"samples_to_{th}"][2] for r in rs])
            shown = np.isfinite(med)
            ax.barh(y[shown] + off, med[shown], height=0.38, color=color, label=f"to {th}")
            hi = np.where(np.isfinite(hi), hi, budget * 2.5)  # a seed that never got there: to the frame's edge
            err = np.vstack([med[shown] - lo[shown], hi[shown] - med[shown]])
            ax.errorbar(med[shown], y[shown] + off, xerr=err, fmt="none", ecolor="k", elinewidth=0.8, capsize=2)
            for yi, r in zip(y[~shown], [r for r, s in zip(rs, shown) if not s]):
                txt = "diverged" if r["diverged_seeds"] * 2 > r["seeds"] else "not reached"
                ax.text(1.5, yi + off, txt, va="center", fontsize=6.5, color="#444")
        ax.axvline(budget, color="k", ls=":", lw=1, label="budget")
        ax.set_xscale("log")
        ax.set_xlim(1, budget * 3)
        ax.set_yticks(y, [f"{r['algorithm']} ({r['output']})" for r in rs], fontsize=8)
        ax.invert_yaxis()
        ax.set_title(task, fontsize=9)
        ax.set_xlabel("agent-samples (median, 5-95 % band over seeds)", fontsize=8)
        ax.grid(alpha=0.3, axis="x", which="both")
    for ax in axes.ravel()[len(tasks) :]:
        ax.axis("off")
    handles, labels = axes.ravel()[0].get_legend_handles_labels()  # below the panels, where it covers no bar
    fig.legend(handles, labels, loc="lower center", ncol=3, fontsize=8, frameon=False)
    fig.suptitle(
        "agent-samples until every agent's value error |Phi (w_i - w*)|_d / |Phi w*|_d stays within 10 % / 1 %"
        "\n(step sizes tuned on separate seeds; each method's better output, last iterate or tail average)",
        fontsize=10,
    )
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    fig.savefig(path, dpi=120)
    plt.close(fig)


def write_docs(table: str, figure: Path) -> None:
    """The table between the markers of docs/benchmarks.md, and the figure beside it."""
    doc = DOCS / "benchmarks.md"
    text = doc.read_text()
    if BEGIN not in text or END not in text:
        raise SystemExit(f"{doc} lacks the markers {BEGIN} ... {END} around its time-to-accuracy table")
    new = re.sub(re.escape(BEGIN) + ".*?" + re.escape(END), lambda _: f"{BEGIN}\n{table}\n{END}", text, flags=re.S)
    doc.write_text(new)
    shutil.copyfile(figure, DOCS / "time_to_accuracy.png")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tasks", default=",".join(TASKS))
    ap.add_argument("--algorithms", default=",".join(ALGORITHMS))
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--iterations", type=int, default=None, help="override every task's budget (iterations)")
    ap.add_argument("--backend", default="numba", choices=("numba", "numpy"))
    ap.add_argument("--out", default="benchmarks/results")
    ap.add_argument("--no-docs", dest="docs", action="store_false", help="leave docs/benchmarks.md as it is")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    rows = []
    for task in args.tasks.split(","):
        rows += task_rows(
            task.strip(), [a.strip() for a in args.algorithms.split(",")], args.seeds, args.iterations, args.backend
        )
    total = time.perf_counter() - t0
    header = (
        f"Measured {datetime.date.today().isoformat()} on {machine()}; {args.seeds} seeds per algorithm, step "
        f"sizes and outputs tuned on {TUNE_SEEDS} separate seeds, {args.backend} backend; whole benchmark "
        f"{total:.0f} s (`python benchmarks/time_to_accuracy.py`)."
    )
    table = markdown(rows, header)
    (out / "time_to_accuracy.md").write_text(table)
    (out / "time_to_accuracy.json").write_text(
        json.dumps({"machine": machine(), "seconds": total, "rows": rows}, indent=2, default=float)
    )
    plot(rows, out / "time_to_accuracy.png")
    if args.docs:
        write_docs(table, out / "time_to_accuracy.png")
    print(table)
    print(f"wrote {out}/time_to_accuracy.md, .json, .png" + (" and docs/benchmarks.md" if args.docs else ""))


if __name__ == "__main__":
    main()
