"""Figures from results: iterates against k (like the paper's Fig. 2) and error curves with bands over seeds."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from dgtd.run.loop import RunResult  # noqa: E402
from dgtd.run.results import atomic_write  # noqa: E402


def _save(fig, path: Path) -> None:
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=120, bbox_inches="tight")
    plt.close(fig)
    atomic_write(path, buf.getvalue())


def plot_iterates(result: RunResult, path: Path, seed: int = 0, max_components: int = 6) -> bool:
    """Every agent's w_k components against k for one seed, with w* dashed (the paper's Fig. 2)."""
    if result.w_trace is None:
        return False
    W = result.w_trace[:, seed]
    C, N, q = W.shape
    fig, ax = plt.subplots(figsize=(7, 4))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for f in range(min(q, max_components)):
        col = colors[f % len(colors)]
        for i in range(N):
            ax.plot(result.steps, W[:, i, f], color=col, lw=0.8, alpha=0.8, label=f"w[{f}], agents 1..{N}" if i == 0 else None)
        ax.axhline(result.w_star[f], color=col, ls="--", lw=1.2, label=f"w*[{f}] = {result.w_star[f]:.3f}")
    settled = W[len(W) // 3:, :, : min(q, max_components)]
    settled = settled[np.isfinite(settled)]  # a diverged run is NaN from where it was stopped
    lo = min(settled.min(initial=np.inf), result.w_star[:max_components].min())
    hi = max(settled.max(initial=-np.inf), result.w_star[:max_components].max())
    pad = 0.15 * (hi - lo) + 1e-9
    ax.set_ylim(lo - pad, hi + pad)  # the early transient can reach the projection box; keep the settling readable
    ax.set_xscale("log")
    ax.set_xlabel("iteration k (log scale)")
    ax.set_ylabel("w_k of every agent")
    ax.set_title(f"DGTD iterates (seed {seed}, {N} agents)")
    ax.legend(fontsize=7, ncol=2)
    ax.grid(alpha=0.3)
    _save(fig, path)
    return True


def band(ax, x, Y, label, color=None):
    """Median over seeds with the min-max band; Y is (checkpoints, seeds)."""
    med = np.median(Y, axis=1)
    line, = ax.plot(x, med, label=label, color=color)
    if Y.shape[1] > 1:
        ax.fill_between(x, Y.min(axis=1), Y.max(axis=1), color=line.get_color(), alpha=0.2)


def plot_errors(result: RunResult, path: Path) -> None:
    """Relative error (last and averaged, worst agent), consensus error and MSPBE against k, log scales."""
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    x = result.steps
    m = result.metrics
    band(axes[0], x, m["error_last"], "last iterate")
    band(axes[0], x, m["error_avg"], "averaged iterate")
    axes[0].set_title("max over agents of |w_i - w*|_inf / |w*|_inf")
    # log axes need > 0; NaN marks checkpoints after a run diverged
    floor = lambda Y: np.maximum(Y, 1e-12 * max(float(np.nanmax(Y, initial=0.0)), 1e-300))  # noqa: E731
    band(axes[1], x, floor(m["consensus"]), "sum_i |w_i - mean w|^2")
    axes[1].set_title("consensus error")
    band(axes[2], x, floor(m["mspbe_last"]), "last iterate")
    band(axes[2], x, floor(m["mspbe_avg"]), "averaged iterate")
    axes[2].set_title("MSPBE of the average reward (worst agent)")
    for ax in axes:
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("iteration k")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    _save(fig, path)


def scenario_figures(report, result, source, out) -> list[str]:
    """The figures of a scenario's own report (the patrol world's maps, ...) into ``out``; returns the names
    written, none for a report without figures."""
    from dgtd.plots.robots import report_figures

    return report_figures(report, result, source, out)
