"""Figures from results: iterates against k (like the paper's Fig. 2) and error curves with bands over seeds."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from dgtd.plots.bands import BAND, BAND_WORDS, band, median_band  # noqa: E402,F401
from dgtd.run.loop import RunResult  # noqa: E402
from dgtd.run.results import atomic_write  # noqa: E402


def read_metrics(path: Path, fix: str, column: str | None = None) -> tuple:
    """(the checkpoints' steps (C,), {label: {metric: (C, seeds)}}, the rows) of a metrics.csv, every number checked
    (a missing, bad or negative one is one line ending in ``fix``); the rows grouped by their ``column`` (a learners'
    comparison's "learners"), or all under None."""
    from dgtd.errors import DgtdInputError
    from dgtd.files import numbers, read_csv

    rows = read_csv(path, "results file", fix, required=("seed", "step", "metric", "value"))
    if not rows:
        raise DgtdInputError(f"results file {path} holds no rows; {fix}")
    step_of, seed_of, values = (
        numbers(rows, name, kind, path, "results file", fix)
        for name, kind in (("step", int), ("seed", int), ("value", float))
    )
    if step_of.min() < 0 or seed_of.min() < 0:
        raise DgtdInputError(f"results file {path} has negative steps or seeds; {fix}")
    steps, seeds = np.unique(step_of), 1 + int(seed_of.max())
    grouped: dict = {}
    for row, k, b, x in zip(rows, step_of, seed_of, values):
        metrics = grouped.setdefault(None if column is None else row[column], {})
        metrics.setdefault(row["metric"], np.full((len(steps), seeds), np.nan))[np.searchsorted(steps, k), b] = x
    return steps, grouped, rows


def _save(fig, path: Path) -> None:
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=120, bbox_inches="tight")
    plt.close(fig)
    atomic_write(path, buf.getvalue())


def plot_iterates(
    result: RunResult, path: Path, seed: int = 0, max_components: int = 4, max_agents: int = 10, algorithm: str = ""
) -> bool:
    """Every agent's w_k components against k for one seed, with w* dotted (the paper's Fig. 2): one colour per
    agent, one line style per component; the title says which components and agents are shown."""
    if result.w_trace is None:
        return False
    W = result.w_trace[:, seed]
    C, N, q = W.shape
    shown_q, shown_n = min(q, max_components), min(N, max_agents)
    # Of many components, the largest |w*|: the first ones can be all near zero (Example 2's corner cells).
    picked = np.arange(q) if shown_q == q else np.sort(np.argsort(-np.abs(result.w_star), kind="stable")[:shown_q])
    W = W[:, :, picked]
    w_star = result.w_star[picked]
    fig, ax = plt.subplots(figsize=(8, 4.6))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    styles = ["-", "--", ":", "-."]
    shown = W[:, :shown_n]
    settled = shown[len(W) // 3 :]
    settled = settled[np.isfinite(settled)]  # a diverged run is NaN from where it was stopped
    lo = min(settled.min(initial=np.inf), w_star.min())
    hi = max(settled.max(initial=-np.inf), w_star.max())
    pad = 0.15 * (hi - lo) + 1e-9
    lo, hi = lo - pad, hi + pad
    # The early transient can sit on the projection boxes, far off this scale: those checkpoints are shaded and
    # named rather than drawn as a comb of vertical lines.
    off = np.any((shown < lo) | (shown > hi), axis=(1, 2))
    early = int(np.flatnonzero(off).max()) + 1 if off[: max(1, len(W) // 3)].any() else 0
    if early:
        ax.axvspan(result.steps[0], result.steps[early - 1], color="0.9", lw=0)
        ax.text(
            np.sqrt(result.steps[0] * result.steps[early - 1]),
            hi - 0.05 * (hi - lo),
            f"k < {result.steps[early - 1]:,}: off this scale\n(the iterates swing between the boxes)",
            ha="center",
            va="top",
            fontsize=7,
            color="0.35",
        )
    for i in range(shown_n):
        for f in range(shown_q):
            ax.plot(
                result.steps[early:],
                shown[early:, i, f],
                color=colors[i % len(colors)],
                ls=styles[f % len(styles)],
                lw=0.9,
                alpha=0.85,
                label=f"agent {i + 1}" if f == 0 else None,
            )
    for f in range(shown_q):
        ax.axhline(
            w_star[f],
            color="black",
            ls=styles[f % len(styles)],
            lw=1.6,
            alpha=0.6,
            label=f"w*[{picked[f] + 1}] = {w_star[f]:.3g} ({styles[f % len(styles)]})",
        )
    ax.set_ylim(lo, hi)
    ax.set_xlim(result.steps[0], result.steps[-1])
    ax.set_xscale("log")
    ax.set_xlabel("iteration k (log scale)")
    ax.set_ylabel("w_k")
    what = (
        f"the {shown_q} of {q} components with the largest |w*|"
        if shown_q < q
        else f"all {q} component{'s' if q > 1 else ''}"
    )
    who = f"agents 1-{shown_n} of {N}" if shown_n < N else f"{N} agent{'s' if N > 1 else ''}"
    ax.set_title(f"{algorithm + ' ' if algorithm else ''}iterates, seed {seed}: {what}, {who}", fontsize=10)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    ax.grid(alpha=0.3)
    _save(fig, path)
    return True


def _log_or_zero(ax, x, Y, label):
    """Y on a log axis, or, when it is zero throughout (a single learner, exact consensus), a note saying so.

    Exact zeros (agents that have not exchanged anything yet) have no place on a log axis: they are left out, not
    drawn at an invented floor, and the legend says until when the value was zero."""
    if not np.any(np.nan_to_num(Y, nan=0.0) > 0):
        ax.text(0.5, 0.5, "zero throughout", transform=ax.transAxes, ha="center", va="center", color="gray")
        return False
    zero = np.all(Y == 0, axis=1)
    if zero.any():
        n = int(zero.sum())
        last = int(x[np.flatnonzero(zero).max()])
        label += f" (zero at {n} checkpoint{'s' if n > 1 else ''} up to k = {last:,}, not drawn)"
    band(ax, x, np.where(Y > 0, Y, np.nan), label)  # NaN also marks checkpoints after a divergence
    ax.set_yscale("log")
    return True


def plot_errors(result: RunResult, path: Path) -> None:
    """Relative error (last, averaged and tail-averaged iterate, worst agent), consensus error and MSPBE against k,
    log scales. The tail average starts at the tail's first checkpoint."""
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2), gridspec_kw={"wspace": 0.32})
    x = result.steps
    m = result.metrics
    colors = {"last": "C0", "avg": "C1", "tail": "C2"}
    for key, label, style in (
        ("error_last", "last, weights", "-"),
        ("error_avg", "averaged, weights", "-"),
        ("error_tail", "tail average, weights", "-"),
        ("value_error_last", "last, values", "--"),
        ("value_error_avg", "averaged, values", "--"),
        ("value_error_tail", "tail average, values", "--"),
    ):
        # results saved before the value and tail errors existed have the others only
        if key in m and np.isfinite(m[key]).any():
            band(axes[0], x, m[key], label, color=colors[key.rsplit("_", 1)[1]])
            axes[0].get_lines()[-1].set_linestyle(style)
    axes[0].set_yscale("log")
    axes[0].set_title("worst agent's relative error")
    axes[0].set_ylabel("weights: |w_i - w*|_inf / |w*|_inf\nvalues: |Phi (w_i - w*)|_d / |Phi w*|_d")
    _log_or_zero(axes[1], x, m["consensus"], "sum_i |w_i - mean w|^2")
    axes[1].set_title("consensus error")
    axes[1].set_ylabel("sum_i |w_i - mean_j w_j|^2")
    _log_or_zero(axes[2], x, m["mspbe_last"], "last iterate")
    _log_or_zero(axes[2], x, m["mspbe_avg"], "averaged iterate")
    axes[2].set_title("MSPBE of the average reward (worst agent)")
    axes[2].set_ylabel("MSPBE")
    seeds = m["error_last"].shape[1]
    for ax in axes:
        ax.set_xscale("log")
        ax.set_xlim(x[0], x[-1])
        ax.set_xlabel("iteration k")
        ax.grid(alpha=0.3, which="both")
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2, frameon=False)
    fig.suptitle(f"median over {seeds} seeds, {BAND_WORDS}" if seeds > 1 else "one seed (no band)", fontsize=9)
    _save(fig, path)


def scenario_figures(report, result, source, out) -> list[str]:
    """The figures of a scenario's own report (the patrol world's maps, ...) into ``out``; returns the names
    written, none for a report without figures."""
    from dgtd.plots.robots import report_figures
    from dgtd.plots.values import value_figures

    return report_figures(report, result, source, out) + value_figures(report, result, out)
