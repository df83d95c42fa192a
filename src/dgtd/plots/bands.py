"""The bands drawn over seeds: the median and the 5th to 95th percentile, in every figure alike."""

from __future__ import annotations

import warnings

import numpy as np

BAND = (5.0, 95.0)  # the percentiles over seeds of every band drawn: a 90 % band
BAND_WORDS = "band: 5th to 95th percentile over seeds"


def median_band(Y: np.ndarray):
    """Median over seeds (NaN where half the seeds or more are NaN: diverged, or a value left out) and the 90 % band
    (`BAND`, linear interpolation between seeds) of the others; Y is (checkpoints, seeds)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        alive = np.isfinite(Y).sum(axis=1)
        med = np.where(alive * 2 > Y.shape[1], np.nanmedian(Y, axis=1), np.nan)
        lo, hi = np.nanpercentile(Y, BAND, axis=1)
        return med, lo, hi


def band(ax, x, Y, label, color=None):
    """Median over seeds with the 90 % band (`median_band`); returns the median's line."""
    med, lo, hi = median_band(Y)
    (line,) = ax.plot(x, med, label=label, color=color)
    if Y.shape[1] > 1:
        ax.fill_between(x, lo, hi, color=line.get_color(), alpha=0.2)
    return line
