"""The results store of a sweep: per-job files, written atomically, and one long-format table.

Layout of a sweep directory::

    config.toml            the experiment (grid and executor options included): `dgtd sweep` it again
    sweep.json             the jobs in grid order, each with its grid point and status
    results.parquet        one row per job, seed, checkpoint and metric (results.csv without pyarrow)
    jobs/ID.npz            a job's checkpoint steps and metrics (C, seeds), bit for bit
    jobs/ID.json           a job's summary (exact solution, estimates, errors, resolved config); written
                           last, so its presence means the job is finished
    jobs/ID.toml           the job's fully resolved config: `dgtd run jobs/ID.toml` runs it alone

The table is rebuilt from the job files in grid order, so it does not depend on the order in which jobs
finished, on the executor, or on how many times the sweep was interrupted.
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Any

import numpy as np

from dgtd.errors import DgtdInputError
from dgtd.run.results import atomic_write, atomic_write_json

METRIC_COLUMNS = ("algorithm", "seed", "step", "metric", "value")


def have_pyarrow() -> bool:
    try:
        import pyarrow  # noqa: F401
        import pyarrow.parquet  # noqa: F401
    except ImportError:
        return False
    return True


def table_format(requested: str) -> str:
    """'parquet' or 'csv' for a requested 'auto', 'parquet' or 'csv'."""
    if requested == "auto":
        return "parquet" if have_pyarrow() else "csv"
    if requested == "parquet" and not have_pyarrow():
        raise DgtdInputError("a Parquet table needs pyarrow: pip install 'dgtd[parquet]', or use format = 'csv'")
    return requested


class SweepStore:
    """Files of one sweep directory (see the module docstring)."""

    def __init__(self, root: Path, fmt: str = "auto"):
        self.root = Path(root)
        self.jobs = self.root / "jobs"
        self.format = table_format(fmt)

    @property
    def table_path(self) -> Path:
        return self.root / f"results.{self.format}"

    def begin(self, config_toml: str) -> None:
        """Create the directory, drop temporary files a killed writer left, and write config.toml."""
        self.jobs.mkdir(parents=True, exist_ok=True)
        for tmp in [*self.root.glob(".*.tmp"), *self.jobs.glob(".*.tmp")]:
            tmp.unlink(missing_ok=True)
        atomic_write(self.root / "config.toml", config_toml.encode())

    def done(self, job_id: str) -> bool:
        """True when the job's summary and arrays are both there and readable."""
        try:
            summary = json.loads((self.jobs / f"{job_id}.json").read_text())
            with np.load(self.jobs / f"{job_id}.npz", allow_pickle=False) as data:
                data["steps"]
        except (OSError, ValueError, KeyError, EOFError):
            return False
        return summary.get("job") == job_id

    def write_job(self, job_id: str, point: dict, config_toml: str, result: dict) -> None:
        """A finished job: arrays, resolved config, then the summary (the 'finished' mark) last."""
        buf = io.BytesIO()
        np.savez(buf, steps=result["steps"], **{f"metric.{k}": v for k, v in result["metrics"].items()})
        atomic_write(self.jobs / f"{job_id}.npz", buf.getvalue())
        atomic_write(self.jobs / f"{job_id}.toml", config_toml.encode())
        atomic_write_json(
            self.jobs / f"{job_id}.json",
            {"job": job_id, "point": point, "algorithm": result["algorithm"], **result["summary"]},
        )
        (self.jobs / f"{job_id}.error.txt").unlink(missing_ok=True)

    def write_error(self, job_id: str, message: str) -> None:
        atomic_write(self.jobs / f"{job_id}.error.txt", (message + "\n").encode())

    def job_columns(self, job_id: str, point: dict) -> dict:
        """A finished job's rows as columns: its grid point, then algorithm, seed, step, metric, value."""
        summary = json.loads((self.jobs / f"{job_id}.json").read_text())
        with np.load(self.jobs / f"{job_id}.npz", allow_pickle=False) as data:
            steps = data["steps"]
            metrics = {k.removeprefix("metric."): data[k] for k in data.files if k.startswith("metric.")}
        C, B = len(steps), next(iter(metrics.values())).shape[1]
        n = len(metrics) * C * B
        cols: dict[str, Any] = {"job": [job_id] * n, **{k: [v] * n for k, v in point.items()}}
        cols["algorithm"] = [summary["algorithm"]] * n
        cols["seed"] = np.tile(np.arange(B), C * len(metrics))
        cols["step"] = np.tile(np.repeat(steps, B), len(metrics))
        cols["metric"] = [m for m in metrics for _ in range(C * B)]
        cols["value"] = np.concatenate([v.ravel() for v in metrics.values()])
        return cols

    def write_table(self, jobs) -> Path | None:
        """The long table of the finished ``jobs`` [(id, point)], in their order; None when none is finished."""
        parts = [self.job_columns(j, p) for j, p in jobs if self.done(j)]
        if not parts:
            return None
        names = list(parts[0])
        cols: dict[str, Any] = {
            k: [x for part in parts for x in part[k]]
            if not isinstance(parts[0][k], np.ndarray)
            else np.concatenate([part[k] for part in parts])
            for k in names
        }
        if self.format == "parquet":
            import pyarrow as pa
            import pyarrow.parquet as pq

            buf = io.BytesIO()
            pq.write_table(pa.table({k: pa.array(v) for k, v in cols.items()}), buf)
            data = buf.getvalue()
        else:
            text = io.StringIO()
            w = csv.writer(text, lineterminator="\n")
            w.writerow(names)
            w.writerows(
                zip(
                    *(
                        ["" if x is None else x for x in cols[k]] if isinstance(cols[k], list) else cols[k].tolist()
                        for k in names
                    )
                )
            )
            data = text.getvalue().encode()
        atomic_write(self.table_path, data)
        return self.table_path


def _cell(text: str):
    """A grid value read back from CSV: None, bool, int, float or the string itself."""
    if text == "":
        return None
    if text in ("True", "False"):
        return text == "True"
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def read_table(path: Path) -> dict:
    """A sweep table (Parquet or CSV) as columns {name: list or array}; a damaged table is a `DgtdInputError`."""
    from dgtd.errors import DgtdInputError
    from dgtd.files import read_csv

    path = Path(path)
    fix = "delete it and run the sweep again (finished jobs are kept and skipped)"
    required = ("job", "seed", "step", "metric", "value")
    if path.suffix == ".parquet":
        import pyarrow.parquet as pq

        try:
            cols = pq.read_table(path).to_pydict()
        except (OSError, ValueError) as e:  # pyarrow's ArrowInvalid is a ValueError
            raise DgtdInputError(f"sweep table {path} cannot be read ({type(e).__name__}); {fix}") from None
        missing = [k for k in required if k not in cols]
        if missing:
            raise DgtdInputError(f"sweep table {path} lacks the column(s) {', '.join(missing)}; {fix}")
        return {k: np.asarray(v) if k in ("seed", "step", "value") else v for k, v in cols.items()}
    rows = read_csv(path, "sweep table", fix, required=required)
    cols = {name: [r[name] for r in rows] for name in (rows[0] if rows else {k: None for k in required})}
    for k in cols:
        if k not in ("job", "algorithm", "metric", *METRIC_COLUMNS):
            cols[k] = [_cell(x) for x in cols[k]]
    for k in ("seed", "step"):
        cols[k] = np.asarray(cols[k], dtype=np.int64)
    cols["value"] = np.asarray(cols["value"], dtype=np.float64)
    return cols
