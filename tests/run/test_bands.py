"""bands.csv: the median and the 90 % band over seeds of every metric at every checkpoint, beside the per-seed
metrics.csv; the figures draw the same band."""

from __future__ import annotations

import csv
from types import SimpleNamespace

import numpy as np

from dgtd.plots import median_band
from dgtd.run.results import bands_csv


def test_bands_are_the_median_and_the_5th_and_95th_percentiles_over_seeds():
    """21 seeds 0, 1, ..., 20 at one checkpoint: median 10, 5th percentile 1, 95th 19 (linear interpolation: the
    p-th percentile of 0..20 is p / 5); a second checkpoint with a diverged seed counts 20 seeds."""
    Y = np.array([np.arange(21.0), np.r_[np.arange(20.0), np.nan]])
    result = SimpleNamespace(steps=np.array([10, 20]), metrics={"error_last": Y})
    rows = list(csv.DictReader(bands_csv({"dgtd": result}).decode().splitlines()))
    assert [(r["step"], r["metric"]) for r in rows] == [("10", "error_last"), ("20", "error_last")]
    assert [float(rows[0][k]) for k in ("median", "q05", "q95")] == [10.0, 1.0, 19.0]
    assert rows[1]["seeds"] == "20" and float(rows[1]["median"]) == 9.5
    med, lo, hi = median_band(Y)
    assert (med[0], lo[0], hi[0]) == (10.0, 1.0, 19.0)


def test_run_writes_bands_csv(run_cli, tmp_path):
    out = tmp_path / "r"
    code, _, err = run_cli(
        "run", "paper-example-1", "-T", "500", "--seeds", "3", "--no-plots", "--no-progress", "--out", out
    )
    assert code == 0, err
    rows = list(csv.DictReader((out / "bands.csv").open()))
    metrics = {r["metric"] for r in rows}
    assert {"error_tail", "value_error_last", "value_error_avg", "value_error_tail"} <= metrics
    assert all(r["seeds"] == "3" for r in rows if r["metric"] == "error_last")
