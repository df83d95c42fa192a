"""``values.png`` of a run on an environment: every agent's value estimate along a trajectory beside the reference's.

What a user of a simulator wants to see first: not weights, whose scale means little with Fourier or tile features,
but the values each agent predicts in the states the team visits, against what they should be.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from dgtd.plots.robots import _save  # noqa: E402
from dgtd.scenarios.user import TrajectoryReport  # noqa: E402


def _broken(x: np.ndarray, restarts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(steps, values) with a gap before every restart, so that no line joins two episodes."""
    k = np.insert(np.arange(len(x), dtype=float), restarts, np.nan)
    return k, np.insert(np.asarray(x, dtype=float), restarts, np.nan)


def value_figures(report, result, out) -> list[str]:
    """``values.png`` for a `TrajectoryReport`; nothing for another report."""
    if not isinstance(report, TrajectoryReport):
        return []
    ref, agents, restarts = report.trajectory(result)
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True, height_ratios=(3, 1.4))
    colours = plt.get_cmap("tab10").colors  # type: ignore[attr-defined]
    for i, v in enumerate(agents):  # the first agent widest: agents in consensus show as nested lines
        width = 1.0 + 2.0 * (len(agents) - 1 - i) / max(len(agents) - 1, 1)
        top.plot(*_broken(v, restarts), color=colours[i % 10], lw=width, label=f"agent {i + 1}")
        bottom.plot(*_broken(v - ref, restarts), color=colours[i % 10], lw=width)
    top.plot(*_broken(ref, restarts), color="black", lw=1.4, ls="--", label="reference phi(s)' w* (LSTD)")
    for ax in (top, bottom):
        for j, t in enumerate(restarts):
            ax.axvline(t - 0.5, color="0.6", lw=0.8, ls=":", label="episode restarts" if ax is top and j == 0 else None)
    bottom.axhline(0.0, color="0.2", lw=0.8)
    top.set_ylabel("value estimate phi(s)' w_i")
    bottom.set_ylabel("minus reference")
    bottom.set_xlabel("step along a fresh trajectory (same policy, streams of its own)")
    top.set_title("every agent's value (tail average, seed 0) along a trajectory, and the reference's")
    bottom.legend(
        *top.get_legend_handles_labels(),
        loc="upper center",
        bbox_to_anchor=(0.5, -0.45),
        ncol=min(len(agents) + 2, 5),
        fontsize=8,
        frameon=False,
    )
    fig.subplots_adjust(hspace=0.08)
    _save(fig, Path(out) / "values.png")
    return ["values.png"]
