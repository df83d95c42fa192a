"""`dgtd run --log tensorboard,mlflow`: every metric of metrics.csv at the same steps, one run per seed, read back with
TensorBoard's and MLflow's own readers; a new run replaces the last one's logs; unknown or missing loggers are one
line before anything runs."""

from __future__ import annotations

import csv
from collections import defaultdict

import numpy as np
import pytest

RUN = ("run", "paper-example-1", "-T", "600", "--seeds", "2", "--checkpoints", "7", "--no-plots", "--no-progress")


def _metrics_csv(out):
    """{seed: {metric: (steps, values)}} from metrics.csv."""
    table: dict = defaultdict(lambda: defaultdict(list))
    with open(out / "metrics.csv") as f:
        for row in csv.DictReader(f):
            table[int(row["seed"])][row["metric"]].append((int(row["step"]), float(row["value"])))
    return {
        seed: {m: tuple(np.array(x) for x in zip(*points)) for m, points in ms.items()} for seed, ms in table.items()
    }


def _tensorboard_holds(accumulator, out, expected: dict) -> None:
    """Each seed's event files in OUT/tensorboard, loaded by TensorBoard's EventAccumulator, hold ``expected``
    ({seed: {metric: (steps, values)}}): the same tags, at the same steps, the values to float32's precision."""
    for seed, metrics in expected.items():
        events = accumulator.EventAccumulator(str(out / "tensorboard" / f"seed-{seed}"), size_guidance={"scalars": 0})
        events.Reload()
        assert sorted(events.Tags()["scalars"]) == sorted(metrics)
        for metric, (steps, values) in metrics.items():
            got = events.Scalars(metric)
            assert [e.step for e in got] == steps.tolist()
            np.testing.assert_array_equal(np.array([e.value for e in got], np.float32), values.astype(np.float32))


def test_tensorboard_event_files_hold_every_metric_of_metrics_csv(tmp_path, run_cli):
    """Each seed's event files, loaded by TensorBoard's EventAccumulator: the same tags as metrics.csv's metrics, at
    the same steps, with its values to float32's precision (TensorBoard keeps scalars as float32). A second run into
    the directory replaces them: no step is there twice."""
    pytest.importorskip("tensorboardX", reason="the tensorboard extra (dgtd[tensorboard]) is not installed")
    accumulator = pytest.importorskip("tensorboard.backend.event_processing.event_accumulator")
    out = tmp_path / "r"
    for _ in range(2):
        code, _, err = run_cli(*RUN, "--log", "tensorboard", "--out", out)
        assert code == 0, err
    expected = _metrics_csv(out)
    assert sorted(p.name for p in (out / "tensorboard").iterdir()) == ["seed-0", "seed-1"]
    _tensorboard_holds(accumulator, out, expected)


def test_mlflow_store_holds_every_metric_of_metrics_csv(tmp_path, run_cli):
    """MLflow's local store OUT/mlflow.db, read with MlflowClient: one run per seed, named seed-B, every metric's
    history at metrics.csv's steps with its values exactly, and the run's settings as parameters."""
    tracking = pytest.importorskip("mlflow.tracking", reason="the mlflow extra (dgtd[mlflow]) is not installed")
    out = tmp_path / "r"
    code, text, err = run_cli(*RUN, "--log", "mlflow,tensorboard", "--out", out)
    assert code == 0, err
    assert "mlflow.db" in text and "INFO" not in err  # MLflow's notes on creating its tables are not shown
    client = tracking.MlflowClient(tracking_uri=f"sqlite:///{out / 'mlflow.db'}")
    (experiment,) = client.search_experiments(filter_string="name = 'r'")
    runs = {r.info.run_name: r for r in client.search_runs([experiment.experiment_id])}
    expected = _metrics_csv(out)
    assert sorted(runs) == [f"seed-{seed}" for seed in sorted(expected)]
    for seed, metrics in expected.items():
        run = runs[f"seed-{seed}"]
        assert run.data.params["scenario"] == "paper-example-1" and run.data.params["algorithm"] == "dgtd"
        assert sorted(run.data.metrics) == sorted(metrics)
        for metric, (steps, values) in metrics.items():
            history = sorted(client.get_metric_history(run.info.run_id, metric), key=lambda m: m.step)
            assert [m.step for m in history] == steps.tolist()
            np.testing.assert_array_equal([m.value for m in history], values)
    assert not list(out.glob(".*.tmp"))


@pytest.mark.parametrize(
    "value, words",
    [("wandb", "log: one or more of tensorboard, mlflow"), ("tensorboard,csv", "got 'csv'")],
)
def test_an_unknown_logger_is_one_line_before_the_run(tmp_path, run_cli, value, words):
    code, _, err = run_cli(*RUN, "--log", value, "--out", tmp_path / "r")
    assert code == 2 and words in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "r" / "metrics.csv").exists()


def test_a_logger_not_installed_says_which_extra_installs_it(monkeypatch):
    import importlib.util

    from dgtd.errors import DgtdInputError
    from dgtd.run import logs

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name: None if name == "mlflow" else real(name))
    with pytest.raises(
        DgtdInputError, match=r"--log mlflow needs mlflow, which is not installed: pip install 'dgtd\[mlflow\]'"
    ):
        logs.log_kinds("mlflow")


def test_a_learning_run_logs_every_metric_of_its_metrics_csv(tmp_path, run_cli):
    """`dgtd learn --log tensorboard`: each seed's event files hold metrics.csv's metrics at its steps (float32), as
    `dgtd run`'s do; config.toml keeps the logger (which `--resume DIR` reads); an unknown logger is one line before
    anything runs."""
    pytest.importorskip("tensorboardX", reason="the tensorboard extra (dgtd[tensorboard]) is not installed")
    accumulator = pytest.importorskip("tensorboard.backend.event_processing.event_accumulator")
    out = tmp_path / "l"
    command = ("learn", "pull-away", "-T", 600, "--checkpoints", 3, "--no-plots", "--no-progress", "--out", out)
    code, text, err = run_cli(*command, "--log", "tensorboard")
    assert code == 0 and "tensorboard/" in text, err
    assert 'log = "tensorboard"' in (out / "config.toml").read_text()
    _tensorboard_holds(accumulator, out, _metrics_csv(out))
    code, _, err = run_cli(*command, "--log", "wandb", "--overwrite")
    assert code == 2 and "log: one or more of tensorboard, mlflow" in err and (out / "tensorboard").exists()
