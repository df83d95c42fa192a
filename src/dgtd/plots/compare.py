"""Figures of `dgtd compare`: error and MSPBE against samples and against bits sent, median and band over seeds."""

from __future__ import annotations

import warnings
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from dgtd.plots import BAND_WORDS, _save, median_band  # noqa: E402


def color(name: str) -> str | None:
    """The algorithm's own colour (`dgtd.algorithms.base`), the same in every figure."""
    from dgtd.algorithms import ALGORITHMS

    return getattr(ALGORITHMS.get(name), "color", None)


def _curve(ax, x, Y, name, floor, top):
    """Median and band of Y (checkpoints, seeds) against x; values above ``top`` (diverging runs) are cut at
    ``top`` so that the converging curves stay readable, and an x marks where the median run stopped. Exact zeros
    (agents that have not exchanged anything yet) have no place on a log axis and are left out."""
    med, lo, hi = median_band(np.where(Y > 0, Y, np.nan))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        xm = np.nanmedian(x, axis=1) if x.ndim == 2 else x
    colour = color(name)
    ax.plot(xm, np.minimum(med, top), label=name, color=colour, lw=1.4)
    if Y.shape[1] > 1:
        ax.fill_between(xm, np.minimum(lo, top), np.minimum(hi, top), color=colour, alpha=0.15, lw=0)
    dead = np.flatnonzero(~np.isfinite(median_band(Y)[0]))  # NaN in Y itself: the seeds were stopped
    if dead.size and dead[0] > 0:  # the median run stopped here: it diverged
        ax.plot(xm[dead[0] - 1], min(med[dead[0] - 1], top), "x", color=colour, ms=9, mew=2)


def _limits(results: dict, metric: str) -> tuple[float, float]:
    """(floor, top) of a log axis: top is 1e3 times the largest initial median, so that diverging runs
    leave the frame instead of squashing the others; floor keeps exact zeros plottable."""
    first = [np.nanmedian(r.metrics[metric][0]) for r in results.values() if np.isfinite(r.metrics[metric][0]).any()]
    live = np.concatenate([r.metrics[metric][np.isfinite(r.metrics[metric])] for r in results.values()])
    top = 1e3 * max(first + [1e-300])
    positive = live[(live > 0) & (live <= top)]
    floor = 1e-3 * float(positive.min()) if positive.size else 1e-300
    return floor, top


def plot_compare(results: dict, path: Path, title: str = "") -> None:
    """2 x 2 panels: worst-agent relative error and MSPBE (last iterates), against agent-samples and against the
    bits the links delivered (the channel's count: 64 per number, or what a compressing channel really sends).
    Algorithms that send nothing appear on the bits panels as a dotted line at their final level."""
    fig, axes = plt.subplots(2, 2, figsize=(12, 8.5))
    for row, (metric, label) in enumerate(
        (
            ("error_last", "last iterate: max_i |w_i - w*|_inf / |w*|_inf"),
            ("mspbe_last", "last iterate: MSPBE of the average reward\n(worst agent)"),
        )
    ):
        floor, top = _limits(results, metric)
        for name, r in results.items():
            Y = r.metrics[metric]
            _curve(axes[row, 0], r.info["counts"]["samples"], Y, name, floor, top)
            if r.info["messages"].max() > 0:
                _curve(axes[row, 1], r.info["counts"]["bits"], Y, name, floor, top)
            elif np.isfinite(median_band(Y)[0][-1]):
                axes[row, 1].axhline(
                    max(median_band(Y)[0][-1], floor),
                    color=color(name),
                    ls=":",
                    lw=1.2,
                    label=f"{name} (no messages; final level)",
                )
            else:
                axes[row, 1].plot([], [], "x", color=color(name), label=f"{name} (no messages; diverged)")
        axes[row, 0].set_ylabel(label)
        axes[row, 0].set_xlabel("agent-samples consumed (N per step)")
        axes[row, 1].set_xlabel("bits delivered over links (a vector of q numbers: 64 q bits)")
    for ax in axes.ravel():
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.grid(alpha=0.3, which="both")
    # One legend for the four panels, below them, where it covers no curve: each algorithm as its curves are drawn
    # (solid), and the dotted level that stands for an algorithm that sends nothing on the message panels.
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], color=color(name), lw=1.4, label=name) for name in results]
    if any(r.info["messages"].max() == 0 for r in results.values()):
        handles.append(Line2D([], [], color="gray", ls=":", lw=1.2, label="sends nothing: its final level (right)"))
    fig.legend(handles=handles, loc="lower center", ncol=4, fontsize=8, frameon=False, bbox_to_anchor=(0.5, -0.01))
    fig.subplots_adjust(bottom=0.12)
    fig.suptitle(
        title + "\nmedian over seeds, " + BAND_WORDS + "; x: the median run diverged; curves beyond 1000x the "
        "largest starting value are cut at the frame's top",
        fontsize=10,
    )
    _save(fig, path)


def plot_consensus(results: dict, path: Path, title: str = "") -> bool:
    """Consensus error sum_i |w_i - mean w|^2 against samples, for the algorithms with one estimate per agent;
    False, and no figure, when none has (only centralised learners compared)."""
    distributed = {name: r for name, r in results.items() if r.w_last.shape[1] > 1}
    if not distributed:
        return False
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    floor = _limits(distributed, "consensus")[0]
    for name, r in distributed.items():  # all agents start equal: no initial level to cut at
        _curve(ax, r.info["counts"]["samples"], r.metrics["consensus"], name, floor, np.inf)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("agent-samples consumed")
    ax.set_ylabel("sum_i |w_i - mean_j w_j|^2")
    ax.set_title(
        title + ": consensus error\n(median over seeds, " + BAND_WORDS + "; exact zeros not drawn)", fontsize=10
    )
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    _save(fig, path)
    return True
