"""`dgtd plot DIR`: figures from saved results alone, for a run and for a sweep."""

from __future__ import annotations

import numpy as np

from dgtd.config import RunSpec, resolve
from dgtd.experiments import parse
from dgtd.plots.results import load_run
from dgtd.run.loop import run
from dgtd.run.results import write_results
from dgtd.sweep import run_sweep


def _png(path) -> bool:
    return path.exists() and path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_run_directory_reads_back_exactly(tmp_path, run_cli):
    problem, network, algorithm, samp, settings, resolved = resolve(
        RunSpec(scenario="paper-example-1", iterations=2000, seeds=3, checkpoints=12, backend="numpy"))
    result = run(problem, network, algorithm, samp, settings)
    write_results(tmp_path, result, resolved.to_dict())
    saved = load_run(tmp_path)
    np.testing.assert_array_equal(saved.steps, result.steps)
    for name, values in result.metrics.items():
        np.testing.assert_array_equal(saved.metrics[name], values)  # CSV keeps every float's digits
    np.testing.assert_array_equal(saved.w_trace, result.w_trace)
    code, out, err = run_cli("plot", tmp_path)
    assert code == 0, err
    assert _png(tmp_path / "errors.png") and _png(tmp_path / "iterates.png")


def test_a_sweep_directory_gives_curves_and_final_errors(tmp_path, run_cli):
    exp = parse({"scenario": "paper-example-1", "iterations": 1500, "seeds": 2, "checkpoints": 8, "backend": "numpy",
                 "grid": {"alpha0": [1.0, 5.0], "kappa": [0.0, 1.0, 2.0]}, "sweep": {"workers": 2}})
    run_sweep(exp, tmp_path / "two", echo=lambda s: None, progress=False)
    code, out, err = run_cli("plot", tmp_path / "two")
    assert code == 0, err
    for name in ("curves.png", "final_error_avg.png", "final_error_last.png"):
        assert _png(tmp_path / "two" / name), name
    assert "final_error_avg.png" in out


def test_plot_refuses_a_directory_without_results(tmp_path, run_cli):
    code, _, err = run_cli("plot", tmp_path)
    assert code == 2 and "not a results directory" in err
