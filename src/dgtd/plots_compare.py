"""Figures of `dgtd compare`: error and MSPBE against samples and against messages, median and band over seeds."""

from __future__ import annotations

import warnings
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from dgtd.plots import _save  # noqa: E402

COLORS = {"dgtd": "#d62728", "gtd2": "#1f77b4", "tdc": "#17becf", "td0": "#7f7f7f", "consensus-td0": "#2ca02c",
          "pd-td": "#9467bd", "local": "#ff7f0e"}


def _median_band(Y: np.ndarray):
    """Median over seeds (NaN once half the seeds have diverged) and the min-max band of the live seeds."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        alive = np.isfinite(Y).sum(axis=1)
        med = np.where(alive * 2 > Y.shape[1], np.nanmedian(Y, axis=1), np.nan)
        return med, np.nanmin(Y, axis=1), np.nanmax(Y, axis=1)


def _curve(ax, x, Y, name, floor):
    med, lo, hi = _median_band(np.maximum(Y, floor))
    xm = np.nanmedian(x, axis=1) if x.ndim == 2 else x
    color = COLORS.get(name)
    ax.plot(xm, med, label=name, color=color, lw=1.4)
    if Y.shape[1] > 1:
        ax.fill_between(xm, lo, hi, color=color, alpha=0.15, lw=0)
    dead = np.flatnonzero(~np.isfinite(med))
    if dead.size and dead[0] > 0:  # mark where the median run stopped (divergence)
        ax.plot(xm[dead[0] - 1], med[dead[0] - 1], "x", color=color, ms=9, mew=2)


def plot_compare(results: dict, path: Path, title: str = "") -> None:
    """2 x 2 panels: worst-agent relative error and MSPBE (last iterates), against agent-samples and against
    parameter vectors sent. Algorithms that send nothing appear on the message panels as a dotted line at
    their final level."""
    fig, axes = plt.subplots(2, 2, figsize=(12, 8.5))
    for row, (metric, label) in enumerate((("error_last", "max_i |w_i - w*|_inf / |w*|_inf"),
                                           ("mspbe_last", "MSPBE of the average reward (worst agent)"))):
        vals = [r.metrics[metric] for r in results.values()]
        finite = np.concatenate([v[np.isfinite(v)].ravel() for v in vals] + [np.array([1.0])])
        floor = 1e-12 * max(float(finite.max()), 1e-300)
        for name, r in results.items():
            Y = r.metrics[metric]
            _curve(axes[row, 0], r.metrics["samples"], Y, name, floor)
            if r.info["messages"].max() > 0:
                _curve(axes[row, 1], r.metrics["messages"], Y, name, floor)
            else:
                med = _median_band(np.maximum(Y, floor))[0]
                last = med[np.isfinite(med)]
                if last.size:
                    axes[row, 1].axhline(last[-1], color=COLORS.get(name), ls=":", lw=1.2,
                                         label=f"{name} (no messages; final level)")
        axes[row, 0].set_ylabel(label)
        axes[row, 0].set_xlabel("agent-samples consumed (N per step)")
        axes[row, 1].set_xlabel("parameter vectors sent over links")
    for ax in axes.ravel():
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7)
    fig.suptitle(title + "  (median over seeds, band: min-max; x: divergence)", fontsize=10)
    _save(fig, path)


def plot_consensus(results: dict, path: Path, title: str = "") -> None:
    """Consensus error sum_i |w_i - mean w|^2 against samples, for the algorithms with one estimate per agent."""
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    for name, r in results.items():
        Y = r.metrics["consensus"]
        if np.nanmax(np.abs(Y), initial=0.0) > 0:
            _curve(ax, r.metrics["samples"], Y, name, 1e-14)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("agent-samples consumed")
    ax.set_ylabel("sum_i |w_i - mean_j w_j|^2")
    ax.set_title(title + " consensus error", fontsize=10)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    _save(fig, path)
