"""`dgtd sweep` of learning runs (`dgtd.sweep.learning`): a [learn] table and a [grid] of `dgtd learn`'s options; every
job's numbers are the `dgtd learn` run's of its options, a second run skips the finished jobs, and a bad file or grid
point is one line before any job runs."""

from __future__ import annotations

import csv

import pytest
from helpers import one_line_error

SWEEP = """
[learn]
task = "pull-away"
iterations = 600
seeds = 2
checkpoints = 3
loss = "0.2"

[grid]
actor_step = [0.1, 0.5]
actor = ["networked", "independent"]

[sweep]
workers = 2
"""


def _rows(path, **where) -> dict:
    """{(seed, step, metric): value} of a CSV's rows whose columns equal ``where``."""
    with open(path) as f:
        return {
            (int(r["seed"]), int(r["step"]), r["metric"]): float(r["value"])
            for r in csv.DictReader(f)
            if all(r[k] == str(v) for k, v in where.items())
        }


def test_a_learning_sweep_runs_each_point_as_dgtd_learn_would(run_cli, tmp_path):
    """4 jobs (2 actor steps x 2 actors): the table holds every job's metrics, and the job of actor step 0.5,
    independent actors, equals `dgtd learn` with those options, every metric at every checkpoint exactly; the same
    command again runs nothing."""
    (tmp_path / "s.toml").write_text(SWEEP)
    out = tmp_path / "out"
    code, text, err = run_cli("sweep", tmp_path / "s.toml", "--out", out, "--format", "csv", "--no-progress")
    assert code == 0 and "4 jobs run" in text, err
    table = _rows(out / "results.csv", actor_step=0.5, actor="independent")
    assert len(table) == 2 * 3 * 6  # seeds x checkpoints x metrics
    code, _, err = run_cli("learn", "pull-away", "-T", 600, "--seeds", 2, "--checkpoints", 3, "--loss", "0.2",
                           "--actor-step", 0.5, "--actor", "independent", "--no-plots", "--no-progress",
                           "--out", tmp_path / "one")  # fmt: skip
    assert code == 0, err
    assert _rows(tmp_path / "one" / "metrics.csv") == pytest.approx(table, rel=0, abs=0, nan_ok=True)
    code, text, _ = run_cli("sweep", tmp_path / "s.toml", "--out", out, "--format", "csv", "--no-progress")
    assert code == 0 and "0 jobs run, 4 skipped" in text


@pytest.mark.parametrize(
    "change, words",
    [
        (("actor = [", 'actor = ["bogus", '), "grid point actor_step = 0.1, actor = 'bogus'"),
        (("actor_step = [", "actor_stp = ["), "unknown field 'actor_stp'"),
        (("[sweep]", "[other]"), "not 'other'"),
    ],
)
def test_a_bad_learning_sweep_is_one_line(run_cli, tmp_path, change, words):
    (tmp_path / "s.toml").write_text(SWEEP.replace(*change))
    one_line_error(*run_cli("sweep", tmp_path / "s.toml", "--out", tmp_path / "out"), words)
    assert not (tmp_path / "out").exists()
