"""A run's metrics in the tools users watch their experiments in: TensorBoard's event files and MLflow's local store.

Written once the run's numbers are (after metrics.csv, before the figures), from metrics.csv's own rows
(`dgtd.run.results.metrics_rows`): one run per seed, every metric at every checkpoint, its step the iteration.

- ``tensorboard``: event files in OUT/tensorboard/seed-B/ (`tensorboard --logdir OUT/tensorboard`), one scalar tag
  per metric; TensorBoard keeps scalars as float32, so values agree with metrics.csv to float32's precision.
- ``mlflow``: MLflow's local store OUT/mlflow.db (`mlflow ui --backend-store-uri sqlite:///OUT/mlflow.db`), one
  experiment named after the results directory, one run per seed named seed-B, with the run's settings as
  parameters; values exactly metrics.csv's. MLflow 3 refuses its older folder store (./mlruns) unless told to allow
  it (its "maintenance mode"), so its local store here is the SQLite file it now recommends.

Each is written beside the results and then moved into place, so a directory never holds half of one, and a new run
into the directory replaces the last run's (`remove_logs`).
"""

from __future__ import annotations

import importlib.util
import logging
import os
import shutil
import time
import uuid
from collections import defaultdict
from pathlib import Path

from dgtd.errors import DgtdInputError

# name -> (the module that writes it, the extra that installs it)
LOGGERS = {"tensorboard": ("tensorboardX", "tensorboard"), "mlflow": ("mlflow", "mlflow")}
TENSORBOARD, MLFLOW = "tensorboard", "mlflow.db"  # what each writes in the results directory


def log_kinds(value: str | None) -> tuple[str, ...]:
    """The loggers of ``value`` ('tensorboard', 'mlflow' or both, comma-separated; None or '': none), each checked to
    be known and installed: a one-line refusal otherwise, before anything runs."""
    names = tuple(dict.fromkeys(x.strip() for x in (value or "").split(",") if x.strip()))
    for name in names:
        if name not in LOGGERS:
            raise DgtdInputError(f"log: one or more of {', '.join(LOGGERS)}, comma-separated; got {name!r}")
        module, extra = LOGGERS[name]
        if importlib.util.find_spec(module) is None:
            raise DgtdInputError(
                f"--log {name} needs {module}, which is not installed: pip install 'dgtd[{extra}]' (or leave out --log)"
            )
    return names


def remove_logs(out: Path) -> None:
    """The logs a previous run left in ``out``."""
    shutil.rmtree(Path(out) / TENSORBOARD, ignore_errors=True)
    (Path(out) / MLFLOW).unlink(missing_ok=True)


def write_logs(out: Path, kinds, rows, params: dict) -> list[str]:
    """Write the loggers ``kinds`` of ``rows`` ((algorithm, seed, step, metric, value), as metrics.csv's) into
    ``out``, with ``params`` (the run's settings, name -> value) where the logger keeps them; returns what was
    written."""
    out = Path(out)
    by_seed: dict[int, list] = defaultdict(list)
    for _, seed, step, metric, value in rows:
        by_seed[int(seed)].append((int(step), metric, float(value)))
    written = []
    try:
        if "tensorboard" in kinds:
            _tensorboard(out, by_seed)
            written.append(TENSORBOARD + "/")
        if "mlflow" in kinds:
            _mlflow(out, by_seed, params)
            written.append(MLFLOW)
    finally:  # what a failure or Ctrl-C left half-written goes; what was moved into place stays
        for tmp in out.glob(".*.tmp"):
            shutil.rmtree(tmp, ignore_errors=True) if tmp.is_dir() else tmp.unlink(missing_ok=True)
    return written


def _tensorboard(out: Path, by_seed: dict) -> None:
    from tensorboardX import SummaryWriter

    tmp = out / f".{TENSORBOARD}.tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    for seed, points in sorted(by_seed.items()):
        writer = SummaryWriter(logdir=str(tmp / f"seed-{seed}"), max_queue=len(points) + 1)
        for step, metric, value in points:
            writer.add_scalar(metric, value, global_step=step)
        writer.close()
    shutil.rmtree(out / TENSORBOARD, ignore_errors=True)
    os.replace(tmp, out / TENSORBOARD)


def _mlflow(out: Path, by_seed: dict, params: dict) -> None:
    for name in ("mlflow", "alembic"):  # their notes of creating the store's tables are not the user's business
        logging.getLogger(name).setLevel(logging.WARNING)
    from mlflow.entities import Metric, Param
    from mlflow.tracking import MlflowClient

    # a name of its own: MLflow keeps a store open per address for the life of the process
    tmp = out / f".{MLFLOW}.{os.getpid()}.{uuid.uuid4().hex}.tmp"
    client = MlflowClient(tracking_uri=f"sqlite:///{tmp.resolve()}")
    experiment = client.create_experiment(out.resolve().name or "dgtd")
    settings = [Param(k, str(v)) for k, v in sorted(params.items()) if isinstance(v, str | int | float | bool)]
    now = int(time.time() * 1000)
    for seed, points in sorted(by_seed.items()):
        run = client.create_run(experiment, run_name=f"seed-{seed}", tags={"seed": str(seed)})
        metrics = [Metric(metric, value, now, step) for step, metric, value in points]
        for start in range(0, len(settings), 100):  # MLflow takes at most 100 parameters a batch
            client.log_batch(run.info.run_id, params=settings[start : start + 100])
        for start in range(0, len(metrics), 1000):  # and 1 000 metrics
            client.log_batch(run.info.run_id, metrics=metrics[start : start + 1000])
        client.set_terminated(run.info.run_id)
    os.replace(tmp, out / MLFLOW)
