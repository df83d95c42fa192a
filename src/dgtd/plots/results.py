"""Figures from saved results alone: `dgtd plot DIR` for the directory of a run or of a sweep.

A run's directory gives error, consensus and MSPBE curves with bands over seeds (and the iterates when the
trace was kept); a sweep's gives those curves for every job and the final error against the swept
parameters: a line plot over one parameter, a heat map over two.
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from dgtd.errors import DgtdInputError
from dgtd.files import numbers, read_csv, read_json, read_npz
from dgtd.plots import BAND_WORDS, _save, band, median_band, plot_errors, plot_iterates, plt, read_metrics
from dgtd.run.results import with_agents

# What each metric of a run is, in words, for titles and axes.
METRIC_WORDS = {
    "error_avg": "worst agent's relative error (max norm) of the averaged iterate",
    "error_last": "worst agent's relative error (max norm) of the last iterate",
}
CURVES = (
    ("error_avg", "max relative error, averaged iterate"),
    ("consensus", "consensus error (zeros not drawn)"),
    ("mspbe_avg", "MSPBE, averaged iterate"),
)
CURVE_AXES = ("max_i |w_i - w*|_inf / |w*|_inf", "sum_i |w_i - mean_j w_j|^2", "MSPBE")


def load_run(directory: Path) -> SimpleNamespace:
    """What the figures of a run need, read back from metrics.csv, trajectory.npz and summary.json."""
    fix = f"run it again (dgtd run {directory / 'config.toml'})"
    path = directory / "metrics.csv"
    steps, grouped, rows = read_metrics(path, fix)
    metrics = grouped[None]
    missing = [k for k in ("error_last", "error_avg", "consensus", "mspbe_last", "mspbe_avg") if k not in metrics]
    if missing:
        raise DgtdInputError(f"results file {path} lacks the metric(s) {', '.join(missing)} (cut off?); {fix}")
    summary = read_json(directory / "summary.json", "results file", fix, required=("w_star",))
    trajectory = {}
    if (directory / "trajectory.npz").exists():
        trajectory = read_npz(directory / "trajectory.npz", "results file", fix)
    summary, trajectory = with_agents(directory, summary, trajectory, fix)  # many agents' rows, kept outside

    def saved(key):  # an array of summary.json, None where it is not there (older results)
        return None if summary.get(key) is None else np.asarray(summary[key], dtype=np.float64)

    return SimpleNamespace(
        steps=steps,
        metrics=metrics,
        w_trace=trajectory.get("w_trace"),
        agent_error_last=trajectory.get("agent_error_last"),
        agent_error_avg=trajectory.get("agent_error_avg"),
        w_star=np.asarray(summary["w_star"]),
        w_last=saved("w_last"),
        w_avg=saved("w_avg"),
        w_tail=saved("w_tail"),
        config=summary.get("config", {}),
        algorithm=rows[0].get("algorithm") or summary.get("config", {}).get("algorithm", ""),
    )


def scenario_figures_again(directory: Path, run: SimpleNamespace) -> list[Path]:
    """The figures of a run's scenario (Example 2's maps, snapshots, curves and animation; an env's values), drawn
    again from the saved files: the scenario rebuilt from config.toml, the run's numbers, and scenario.npz where the
    figures need more of the run than its numbers (the robots' paths)."""
    from dgtd.config import scenario_of
    from dgtd.experiments import load
    from dgtd.plots import scenario_figures

    if not (directory / "config.toml").exists() or run.w_last is None:
        return []
    sc = scenario_of(load(str(directory / "config.toml")).config)
    if sc is None or sc.report is None:
        return []
    source = None
    if hasattr(sc.report, "saved"):
        if not (directory / "scenario.npz").exists():
            return []  # results from before the runs saved it: the numbers alone do not draw these figures
        source = sc.report.saved(read_npz(directory / "scenario.npz", "results file", "run it again"))
    return [directory / name for name in scenario_figures(sc.report, run, source, directory)]


def load_compare(directory: Path):
    """({algorithm: what `plot_compare` reads}, title) from a `dgtd compare` directory's metrics.csv and summary."""
    fix = "run the comparison again"
    path = directory / "metrics.csv"
    rows = read_csv(path, "comparison results", fix, required=("algorithm", "seed", "step", "metric", "value"))
    step_of, seed_of = (
        numbers(rows, "step", int, path, "comparison results", fix),
        numbers(rows, "seed", int, path, "comparison results", fix),
    )
    values = numbers(rows, "value", float, path, "comparison results", fix)
    summary = read_json(directory / "summary.json", "comparison results", fix, required=("problem",))
    tables: dict = {}
    for r, k, b, x in zip(rows, step_of, seed_of, values):
        tables.setdefault(r["algorithm"], {}).setdefault(r["metric"], []).append((k, b, x))
    results = {}
    for name, metrics in tables.items():
        need = ("error_last", "mspbe_last", "consensus", "samples", "messages")
        missing = [m for m in need if m not in metrics]
        if missing:
            raise DgtdInputError(f"comparison results {path} lack {', '.join(missing)} for {name}; {fix}")
        arrays = {}
        for metric, entries in metrics.items():
            steps = np.unique([k for k, _, _ in entries])
            seeds = 1 + max(b for _, b, _ in entries)
            Y = np.full((len(steps), seeds), np.nan)
            for k, b, x in entries:
                Y[np.searchsorted(steps, k), b] = x
            arrays[metric] = Y
        counts = {m: arrays[m] for m in ("samples", "messages", "bits", "diverged") if m in arrays}
        if "bits" not in counts:  # (a comparison written before bits were counted: 64 bits per number sent)
            counts["bits"] = arrays["messages"] * 64 * summary.get("n_features", 1)
        one_estimate = not np.any(np.nan_to_num(arrays["consensus"]) > 0)  # a centralised learner
        results[name] = SimpleNamespace(
            metrics=arrays,
            info={"counts": counts, "messages": np.nan_to_num(arrays["messages"][-1])},
            w_last=np.zeros((arrays["error_last"].shape[1], 1 if one_estimate else 2, 1)),
        )
    seeds = next(iter(results.values())).metrics["error_last"].shape[1] if results else 0
    return results, f"{summary['problem']}, {seeds} seeds"


def job_metrics(table: dict) -> dict:
    """{job: (steps (C,), {metric: (C, seeds)})} from the columns of a sweep table."""
    jobs = np.asarray(table["job"])
    out = {}
    for job in dict.fromkeys(table["job"]):
        sel = jobs == job
        steps, seed, value = table["step"][sel], table["seed"][sel], table["value"][sel]
        metric = np.asarray(table["metric"])[sel]
        u = np.unique(steps)
        ms = {}
        for name in dict.fromkeys(metric):
            k = metric == name
            M = np.full((len(u), seed.max() + 1), np.nan)
            M[np.searchsorted(u, steps[k]), seed[k]] = value[k]
            ms[name] = M
        out[job] = (u, ms)
    return out


def _label(point: dict) -> str:
    return ", ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in point.items() if v is not None)


SMALL_MULTIPLES = 12  # more jobs than this: one panel per value of the first swept parameter


def plot_sweep_curves(jobs: dict, points: dict, path: Path) -> None:
    """Each job's median curve over seeds with its 90 % band, one panel per metric; a sweep of more than
    `SMALL_MULTIPLES` jobs draws `plot_sweep_panels` instead, where its curves stay readable."""
    keys = list(dict.fromkeys(k for j in jobs for k in points[j]))  # the grid's own order
    if len(jobs) > SMALL_MULTIPLES and len(keys) > 1:
        return plot_sweep_panels(jobs, points, keys, path)
    fig, axes = plt.subplots(1, len(CURVES), figsize=(14, 4.2), gridspec_kw={"wspace": 0.38})
    # Up to 12 jobs each get a colour and a legend entry; more (of one swept parameter) are coloured by its value,
    # and the legend names those values.
    by = keys[0] if len(jobs) > SMALL_MULTIPLES and keys else None
    groups = sorted({repr(points[j].get(by)) for j in jobs}) if by else list(jobs)
    palette = plt.cm.viridis(np.linspace(0, 0.95, max(len(groups), 1)))
    color_of = {g: c for g, c in zip(groups, palette)}
    labelled = set()
    for job, (steps, ms) in jobs.items():
        group = repr(points[job].get(by)) if by else job
        label = (f"{by} = {points[job].get(by)}" if by else _label(points[job])) if group not in labelled else None
        labelled.add(group)
        for ax, (name, _) in zip(axes, CURVES, strict=True):
            if name in ms:
                # exact zeros (consensus before any link) have no place on a log axis: left out, not floored
                band(
                    ax,
                    steps,
                    np.where(ms[name] > 0, ms[name], np.nan),
                    label if ax is axes[0] else None,
                    color=color_of[group],
                )
    for ax, (_, title), ylabel in zip(axes, CURVES, CURVE_AXES, strict=True):
        ax.set_ylabel(ylabel)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("iteration k")
        ax.set_title(title)
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=6, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=3, frameon=False)
    note = f"{len(jobs)} jobs, median over seeds, {BAND_WORDS}" + (
        f"; colour: {by} (every job with that value)" if by else ""
    )
    fig.suptitle(note, fontsize=9)
    _save(fig, path)


def plot_sweep_panels(jobs: dict, points: dict, keys: list, path: Path, metric: str = "error_avg") -> None:
    """Small multiples: one panel per value of the first swept parameter, and in each one curve (median and band over
    seeds) per setting of the others, in the same colour in every panel; the averaged iterate's worst-agent error."""
    first, rest = keys[0], keys[1:]
    values = sorted({points[j].get(first) for j in jobs}, key=lambda v: (isinstance(v, str), v))
    others = list(dict.fromkeys(_label({k: points[j].get(k) for k in rest}) for j in jobs))
    palette = plt.cm.viridis(np.linspace(0, 0.95, max(len(others), 1)))
    colour = dict(zip(others, palette))
    cols = min(4, len(values))
    rows = -(-len(values) // cols)
    fig, axes = plt.subplots(
        rows, cols, figsize=(3.6 * cols, 3.0 * rows + 0.8), sharex=True, sharey=True, squeeze=False
    )
    for ax, value in zip(axes.ravel(), values):
        for job, (steps, ms) in jobs.items():
            if points[job].get(first) == value and metric in ms:
                label = _label({k: points[job].get(k) for k in rest})
                band(ax, steps, np.where(ms[metric] > 0, ms[metric], np.nan), label, color=colour[label])
        ax.set_title(f"{first} = {value:g}" if isinstance(value, float) else f"{first} = {value}", fontsize=9)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.grid(alpha=0.3, which="both")
    for ax in axes.ravel()[len(values) :]:
        ax.set_visible(False)
    for ax in axes[-1]:
        ax.set_xlabel("iteration k")
    for ax in axes[:, 0]:
        ax.set_ylabel(CURVE_AXES[0], fontsize=8)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    # below the panels, outside them (the saved figure's tight box takes it in): it covers no curve or label
    fig.legend(
        handles,
        labels,
        loc="upper center",
        bbox_to_anchor=(0.5, 0.0),
        ncol=min(4, len(labels)),
        fontsize=7,
        frameon=False,
    )
    fig.suptitle(
        f"{len(jobs)} jobs: {CURVES[0][1]}, median over seeds, {BAND_WORDS}; one panel per {first}", fontsize=9
    )
    _save(fig, path)


def _numeric(values) -> bool:
    return all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)


def _heat_maps(final: dict, points: dict, kx: str, ky: str, panels: dict, metric: str, k_end: int, path: Path) -> None:
    """One heat map of the median final ``metric`` over (kx, ky) per value of the other swept parameters."""
    from matplotlib.colors import LogNorm

    xs = sorted({points[j][kx] for j in final})
    ys = sorted({points[j][ky] for j in final})
    grids = []
    for members in panels.values():
        Z = np.full((len(ys), len(xs)), np.nan)
        for j in members:
            Z[ys.index(points[j][ky]), xs.index(points[j][kx])] = np.median(final[j])
        grids.append(Z)
    positive = np.concatenate([Z[np.isfinite(Z) & (Z > 0)] for Z in grids])
    norm = LogNorm(positive.min(), positive.max()) if positive.size and positive.min() < positive.max() else None
    fig, axes = plt.subplots(
        1, len(grids), figsize=(len(grids) * (1.1 * len(xs) + 1.5) + 1.5, 0.7 * len(ys) + 2), squeeze=False
    )
    for ax, Z, group in zip(axes[0], grids, panels, strict=True):
        im = ax.imshow(Z, origin="lower", cmap="viridis", norm=norm, aspect="auto")
        for (iy, ix), z in np.ndenumerate(Z):
            if np.isfinite(z):  # dark text on the bright end of viridis, white on the dark end
                bright = im.norm(z) > 0.6 if norm is not None else False
                ax.text(ix, iy, f"{z:.2g}", ha="center", va="center", color="k" if bright else "w", fontsize=7)
        ax.set_xticks(range(len(xs)), [f"{x:g}" for x in xs])
        ax.set_yticks(range(len(ys)), [f"{y:g}" for y in ys])
        ax.set_xlabel(kx)
        ax.set_ylabel(ky)
        ax.set_title(_label(dict(group)) or f"k = {k_end:,}", fontsize=9)
    fig.colorbar(im, ax=axes[0].tolist(), label=f"final {metric} at k = {k_end:,} (median over seeds)")
    best = min(final, key=lambda j: np.median(final[j]))
    fig.suptitle(
        f"{METRIC_WORDS.get(metric, metric)} after {k_end:,} iterations, median over seeds; the smallest, "
        f"{np.median(final[best]):.2g}, at {_label({k: points[best][k] for k in (kx, ky, *dict(next(iter(panels))))})}",
        fontsize=9,
    )
    _save(fig, path)


def plot_final_error(jobs: dict, points: dict, keys: list[str], path: Path, metric: str = "error_avg") -> bool:
    """Final ``metric`` (median over seeds, 90 % band) against the swept parameters that vary.

    Two numeric parameters or more: heat maps over the first two, one per value of the others (up to six);
    otherwise a line plot over the numeric parameter (or the categories of the first one), one line per
    value of the others.
    """
    final = {j: ms[metric][-1] for j, (_, ms) in jobs.items() if metric in ms}
    if not final:
        return False
    varying = [k for k in keys if len({repr(points[j].get(k)) for j in final}) > 1]
    numeric = [k for k in varying if _numeric([points[j][k] for j in final if points[j].get(k) is not None])]
    kx: str | None
    if len(numeric) >= 2:
        kx, ky = numeric[:2]
        panels: dict = {}
        for j in final:
            panels.setdefault(tuple((k, points[j].get(k)) for k in varying if k not in (kx, ky)), []).append(j)
        if len(panels) <= 6:
            _heat_maps(final, points, kx, ky, panels, metric, max(int(s[-1]) for s, _ in jobs.values()), path)
            return True
    kx = numeric[0] if numeric else (varying[0] if varying else None)
    others = [k for k in varying if k != kx]
    groups: dict = {}
    for j in final:
        groups.setdefault(tuple((k, points[j].get(k)) for k in others), []).append(j)
    fig, ax = plt.subplots(figsize=(7, 4))
    for group, members in groups.items():
        xs = [points[j].get(kx) if kx else j for j in members]
        order = np.argsort(xs) if kx in numeric else np.arange(len(xs))
        x = [xs[i] if kx in numeric else str(xs[i]) for i in order]
        Y = np.array([final[members[i]] for i in order])
        med, lo, hi = median_band(Y)
        (line,) = ax.plot(x, med, marker="o", label=_label(dict(group)) or None)
        if Y.shape[1] > 1:
            ax.fill_between(x, lo, hi, color=line.get_color(), alpha=0.2)
    if kx in numeric and all(points[j][kx] > 0 for j in final):
        ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(kx or "job")
    ax.set_ylabel(f"final {metric}")
    ax.set_title(f"{METRIC_WORDS.get(metric, metric)} at the end\n(median over seeds, {BAND_WORDS})", fontsize=9)
    ax.grid(alpha=0.3, which="both")
    if len(groups) > 1:
        ax.legend(fontsize=7)
    _save(fig, path)
    return True


def plot_directory(directory: Path) -> list[Path]:
    """Every figure the saved results of a run or sweep directory allow; returns the paths written."""
    directory = Path(directory)
    written = []
    if (directory / "sweep.json").exists():
        from dgtd.run.store import read_table

        index = read_json(
            directory / "sweep.json",
            "sweep index",
            "run the sweep again (it skips finished jobs)",
            required=("jobs", "grid"),
        )
        if not index.get("table"):
            raise DgtdInputError(f"{directory} holds no finished job yet; run the sweep first")
        points = {j["job"]: j["point"] for j in index["jobs"]}
        jobs = job_metrics(read_table(directory / index["table"]))
        from dgtd.plots.learning import learning_sweep_figure

        if learning_sweep_figure(jobs, points, directory / "returns.png"):  # (a sweep of learning runs)
            return [directory / "returns.png"]
        plot_sweep_curves(jobs, points, directory / "curves.png")
        written.append(directory / "curves.png")
        for metric in ("error_avg", "error_last"):
            if plot_final_error(jobs, points, index["grid"], directory / f"final_{metric}.png", metric):
                written.append(directory / f"final_{metric}.png")
        return written
    if not (directory / "metrics.csv").exists():
        raise DgtdInputError(
            f"{directory} is not a results directory of dgtd run, compare or sweep (no metrics.csv or sweep.json)"
        )
    from dgtd.plots.learning import is_learning, learning_figures_again

    if is_learning(directory):  # a learning run's, or a learners' comparison's
        return learning_figures_again(directory)
    if (directory / "agent_errors.npz").exists():  # a comparison: its own figures, one curve per algorithm
        from dgtd.plots.compare import plot_compare, plot_consensus

        results, title = load_compare(directory)
        plot_compare(results, directory / "compare.png", title)
        written.append(directory / "compare.png")
        if plot_consensus(results, directory / "consensus.png", title):
            written.append(directory / "consensus.png")
        return written
    run: Any = load_run(directory)  # a RunResult's fields, read back
    plot_errors(run, directory / "errors.png")
    written.append(directory / "errors.png")
    if plot_iterates(run, directory / "iterates.png", algorithm=run.algorithm):
        written.append(directory / "iterates.png")
    return written + scenario_figures_again(directory, run)
