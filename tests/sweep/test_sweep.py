"""Sweeps on the process pool: grid expansion, the results store, resume, and sweeps killed mid-way."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from conftest import cli_env, dgtd_cmd

from dgtd.config import view
from dgtd.errors import DgtdInputError
from dgtd.experiments import load, parse
from dgtd.run.store import SweepStore, read_table
from dgtd.sweep import expand, run_sweep

SWEEP = """scenario = "paper-example-1"
iterations = {iterations}
seeds = 2
checkpoints = 20
backend = "numba"
progress = false

[grid]
alpha0 = [2.0, 10.0]
kappa = [0.0, 1.0]
edge_prob = [0.5, 0.8, 1.0]
"""


def sweep_file(tmp_path: Path, iterations: int = 100_000) -> Path:
    path = tmp_path / "sweep.toml"
    path.write_text(SWEEP.format(iterations=iterations))
    return path


def table_of(out: Path) -> dict:
    index = json.loads((out / "sweep.json").read_text())
    return read_table(out / index["table"])


def assert_same_table(a: dict, b: dict) -> None:
    assert list(a) == list(b)
    for k in a:
        np.testing.assert_array_equal(np.asarray(a[k]), np.asarray(b[k]), err_msg=k)


def assert_store_intact(out: Path, n_jobs: int) -> None:
    """Every job finished once, every file readable, nothing half-written left behind."""
    index = json.loads((out / "sweep.json").read_text())
    assert len(index["jobs"]) == n_jobs and all(j["status"] == "finished" for j in index["jobs"])
    assert len({j["job"] for j in index["jobs"]}) == n_jobs
    for j in index["jobs"]:
        summary = json.loads((out / "jobs" / f"{j['job']}.json").read_text())
        assert summary["job"] == j["job"] and summary["point"] == j["point"]
        with np.load(out / "jobs" / f"{j['job']}.npz") as data:
            assert data["metric.error_avg"].shape == (len(data["steps"]), 2)
    assert not list(out.rglob("*.tmp"))
    rows = table_of(out)
    metrics = {
        "error_last",
        "error_avg",
        "error_tail",
        "value_error_last",
        "value_error_avg",
        "value_error_tail",
        "consensus",
        "mspbe_last",
        "mspbe_avg",
        "rmspbe_last",
        "rmspbe_avg",
        "rmspbe_tail",
    }
    assert set(rows["metric"]) == metrics
    # jobs x metrics x checkpoints x seeds
    assert len(rows["value"]) == n_jobs * len(metrics) * len(np.unique(rows["step"])) * 2


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """An uninterrupted 12-job sweep on the process pool."""
    tmp = tmp_path_factory.mktemp("ref")
    out = tmp / "out"
    report = run_sweep(load(sweep_file(tmp)), out, echo=lambda s: None, progress=False)
    assert report["ran"] == 12 and not report["failed"]
    return out


def test_grid_is_the_product_in_file_order(tmp_path):
    jobs = expand(load(sweep_file(tmp_path)))
    assert len(jobs) == 12 and len({j.id for j in jobs}) == 12
    assert [j.point for j in jobs[:3]] == [{"alpha0": 2.0, "kappa": 0.0, "edge_prob": e} for e in (0.5, 0.8, 1.0)]
    assert (
        view(jobs[4].config).kappa == 1.0
        and view(jobs[4].config).edge_prob == 0.8
        and view(jobs[4].config).alpha0 == 2.0
    )
    assert all(view(j.config).algorithm == "dgtd" for j in jobs)  # resolved: every field written down


def test_fields_an_algorithm_lacks_are_dropped_and_jobs_merged(monkeypatch):
    """A grid over algorithm x kappa: an algorithm without kappa runs once, with kappa recorded as None."""
    import dgtd.algorithms

    @dataclass(frozen=True)
    class Plain:
        alpha0: float = 1.0
        beta: float = 1.0
        schedule: str = "sqrt"
        name = "plain"

    monkeypatch.setitem(dgtd.algorithms.ALGORITHMS, "plain", Plain)
    exp = parse({"scenario": "paper-example-1", "grid": {"algorithm": ["dgtd", "plain"], "kappa": [0.0, 1.0]}})
    jobs = expand(exp)
    assert [j.point for j in jobs] == [
        {"algorithm": "dgtd", "kappa": 0.0},
        {"algorithm": "dgtd", "kappa": 1.0},
        {"algorithm": "plain", "kappa": None},
    ]
    assert (
        view(jobs[2].config).kappa is None and view(jobs[2].config).alpha0 == 10.0
    )  # the scenario's step sizes carry over


def test_a_bad_grid_point_is_one_clear_error(tmp_path):
    exp = parse({"scenario": "paper-example-1", "grid": {"edge_prob": [0.5, 1.5]}})
    with pytest.raises(DgtdInputError, match="grid point edge_prob = 1.5: edge probabilities must lie in"):
        expand(exp)


def test_sweep_resumes_and_tables_agree_across_formats(tmp_path, reference, run_cli):
    out = tmp_path / "out"
    code, text, err = run_cli("sweep", sweep_file(tmp_path), "--out", out, "--format", "csv", "--workers", "2")
    assert code == 0, err
    assert "12 jobs run" in text and (out / "results.csv").exists()
    assert_same_table(table_of(out), table_of(reference))  # CSV and Parquet hold the same numbers
    code, text, err = run_cli("sweep", sweep_file(tmp_path), "--out", out, "--format", "csv")
    assert code == 0 and "0 jobs run, 12 skipped" in text  # resume is on: the directory exists
    assert_store_intact(out, 12)
    # one job's config alone reproduces its rows
    job = json.loads((out / "sweep.json").read_text())["jobs"][5]["job"]
    code, _, err = run_cli(
        "run", out / "jobs" / f"{job}.toml", "--out", tmp_path / "alone", "--no-plots", "--no-progress"
    )
    assert code == 0, err
    with np.load(out / "jobs" / f"{job}.npz") as data:
        ours = data["metric.error_avg"]
    alone = json.loads((tmp_path / "alone" / "summary.json").read_text())
    store = json.loads((out / "jobs" / f"{job}.json").read_text())
    assert alone["w_last"] == store["w_last"] and np.isfinite(ours).all()


def test_csv_is_used_without_pyarrow(tmp_path, monkeypatch):
    import dgtd.run.store

    monkeypatch.setattr(dgtd.run.store, "have_pyarrow", lambda: False)
    assert SweepStore(tmp_path, "auto").format == "csv"
    with pytest.raises(DgtdInputError, match="needs pyarrow"):
        SweepStore(tmp_path, "parquet")


def test_failed_jobs_are_reported_and_retried_on_rerun(tmp_path, monkeypatch, run_cli):
    """A job that fails in its worker does not stop the others; the sweep exits 1 and a rerun retries it."""
    import dgtd.algorithms

    @dataclass(frozen=True)
    class Ghost:  # known to this process only: the worker processes cannot resolve it
        alpha0: float = 1.0
        beta: float = 1.0
        schedule: str = "sqrt"
        name = "ghost"

    monkeypatch.setitem(dgtd.algorithms.ALGORITHMS, "ghost", Ghost)
    exp = tmp_path / "e.toml"
    exp.write_text(
        'scenario = "paper-example-1"\niterations = 2000\nprogress = false\nbackend = "numpy"\n'
        '[grid]\nalgorithm = ["dgtd", "ghost"]\n'
    )
    code, text, err = run_cli("sweep", exp, "--out", tmp_path / "o", "--workers", "1")
    assert code == 1 and "1 jobs run" in text and "unknown algorithm 'ghost'" in err
    index = json.loads((tmp_path / "o" / "sweep.json").read_text())
    assert [j["status"] for j in index["jobs"]] == ["finished", "failed"]
    code, text, err = run_cli("sweep", exp, "--out", tmp_path / "o", "--workers", "1")
    assert code == 1 and "0 jobs run, 1 skipped" in text


def _finished(out: Path) -> int:
    return len(list((out / "jobs").glob("*.json"))) if (out / "jobs").exists() else 0


def _wait_for(condition, timeout=120.0):
    deadline = time.time() + timeout
    while not condition():
        if time.time() > deadline:
            raise AssertionError("timed out")
        time.sleep(0.05)


@pytest.mark.slow  # a full sweep twice over, with a kill in between
def test_killed_sweep_reruns_to_the_same_table(tmp_path, reference):
    """SIGKILL the sweep (driver and workers) after a few jobs; the rerun finishes the rest, once each."""
    out = tmp_path / "out"
    cmd = dgtd_cmd("sweep", sweep_file(tmp_path), "--out", out, "--workers", "2")
    proc = subprocess.Popen(
        cmd, env=cli_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True
    )
    _wait_for(lambda: _finished(out) >= 3 or proc.poll() is not None)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    done_before = _finished(out)
    assert 3 <= done_before < 12, "the sweep finished before it could be killed; make the jobs longer"
    rerun = subprocess.run(cmd, env=cli_env(), capture_output=True, text=True)
    assert rerun.returncode == 0, rerun.stderr
    assert f"{12 - done_before} jobs run, {done_before} skipped" in rerun.stdout
    assert_store_intact(out, 12)
    assert_same_table(table_of(out), table_of(reference))


def _pool_workers(driver: int) -> list[int]:
    """Process-pool workers of a driver: its children that run multiprocessing's spawn_main."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            ppid = int(stat.read_text().rsplit(")", 1)[1].split()[1])
            cmdline = (stat.parent / "cmdline").read_bytes()
        except (OSError, IndexError, ValueError):
            continue
        if ppid == driver and b"spawn_main" in cmdline:
            found.append(int(stat.parent.name))
    return found


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc to find the pool's worker processes")
def test_killed_pool_worker_is_replaced(tmp_path, reference):
    """SIGKILL one worker of the pool mid-sweep: the pool is rebuilt, unfinished jobs rerun, the table is the same."""
    out = tmp_path / "out"
    proc = subprocess.Popen(
        dgtd_cmd("sweep", sweep_file(tmp_path), "--out", out, "--workers", "2"),
        env=cli_env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    _wait_for(lambda: _finished(out) >= 1 or proc.poll() is not None)
    workers = _pool_workers(proc.pid)
    assert workers and proc.poll() is None
    os.kill(workers[0], signal.SIGKILL)
    stdout, stderr = proc.communicate(timeout=300)
    assert proc.returncode == 0, stderr
    assert "0 failed" in stdout and "a worker process died" in stdout
    assert_store_intact(out, 12)
    assert_same_table(table_of(out), table_of(reference))


def test_ray_executor_without_ray_is_one_line(tmp_path, monkeypatch, run_cli):
    import sys

    monkeypatch.setitem(sys.modules, "ray", None)  # as if Ray were not installed
    code, _, err = run_cli("sweep", sweep_file(tmp_path), "--out", tmp_path / "o", "--executor", "ray")
    assert code == 2 and err.count("\n") == 1 and "pip install 'dgtd[ray]'" in err, err


def test_address_needs_the_ray_executor(tmp_path, run_cli):
    code, _, err = run_cli("sweep", sweep_file(tmp_path), "--out", tmp_path / "o", "--address", "auto")
    assert code == 2 and "executor = 'ray'" in err, err


def test_a_sweep_over_algorithm_names_from_the_registry(tmp_path):
    import dgtd.algorithms

    exp = parse(
        {
            "scenario": "paper-example-1",
            "iterations": 1000,
            "backend": "numpy",
            "progress": False,
            "grid": {"algorithm": list(dgtd.algorithms.ALGORITHMS), "kappa": [0.0, 1.0]},
            "sweep": {"workers": 1},
        }
    )
    report = run_sweep(exp, tmp_path / "o", echo=lambda s: None, progress=False)
    assert report["ran"] == len(expand(exp)) >= 2 and not report["failed"]  # kappa = 0, 1 for dgtd at least
    table = table_of(tmp_path / "o")
    assert set(table["algorithm"]) == set(dgtd.algorithms.ALGORITHMS)
