"""A results directory has one owner: a second writer is refused in one line that names the first, and one kind of
command's results is not written into another's directory without --overwrite."""

from __future__ import annotations

import os

import pytest
from helpers import one_line_error

from dgtd.run.owner import Owner, kind_of

QUICK = ("-T", 20, "--no-progress", "--no-plots")


def test_a_second_writer_is_refused_naming_the_first(run_cli, tmp_path):
    out = tmp_path / "o"
    with Owner(out, "run"):
        code, text, err = run_cli("run", "paper-example-1", *QUICK, "--out", out)
        one_line_error(code, text, err, "is being written by a dgtd run", f"process {os.getpid()}")
        code, text, err = run_cli("compare", "paper-example-1", "-a", "td0", "--seeds", 1, *QUICK, "--out", out)
        one_line_error(code, text, err, "is being written by")
    assert not (out / "summary.json").exists()
    code, _, err = run_cli("run", "paper-example-1", *QUICK, "--out", out)  # the lock went with its owner
    assert code == 0, err


def test_a_run_lets_its_directory_go_when_it_fails(run_cli, tmp_path):
    out = tmp_path / "o"
    one_line_error(*run_cli("run", "paper-example-1", *QUICK, "--seed", -1, "--out", out), "seed")
    code, _, err = run_cli("run", "paper-example-1", *QUICK, "--out", out)
    assert code == 0, err


@pytest.mark.parametrize(
    "there, command",
    [
        ("sweep", ("run", "paper-example-1", *QUICK)),
        ("comparison", ("run", "paper-example-1", *QUICK)),
        ("run", ("compare", "paper-example-1", "-a", "td0", "--seeds", 1, *QUICK)),
    ],
)
def test_one_kind_of_results_is_not_written_into_anothers_directory(run_cli, tmp_path, there, command):
    out = tmp_path / "o"
    out.mkdir()
    made = {"sweep": "jobs", "comparison": "parts", "run": "checkpoint.npz"}[there]
    (out / made).mkdir() if there != "run" else (out / made).write_bytes(b"")
    assert kind_of(out) == there
    one_line_error(*run_cli(*command, "--out", out), f"holds the results of a {there}", "--overwrite")
    code, _, err = run_cli(*command, "--out", out, "--overwrite")
    assert code == 0, err


def test_a_sweep_into_a_runs_directory_is_refused(run_cli, tmp_path):
    out = tmp_path / "o"
    assert run_cli("run", "paper-example-1", *QUICK, "--out", out)[0] == 0
    experiment = tmp_path / "sweep.toml"
    experiment.write_text('scenario = "paper-example-1"\niterations = 20\n\n[grid]\nalpha0 = [1.0, 2.0]\n')
    one_line_error(*run_cli("sweep", experiment, "--out", out, "--no-progress"), "holds the results of a run")


@pytest.mark.parametrize("command", [("run", "paper-example-1"), ("compare", "paper-example-1", "-a", "td0")])
def test_a_results_folder_that_cannot_be_made_is_named_as_such(run_cli, tmp_path, command):
    """--out under a file (or anywhere the folder cannot be made): one line that says it is the results folder and
    what to do, not a bare "[Errno 20] Not a directory"."""
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    code, text, err = run_cli(*command, *QUICK, "--out", blocker / "results")
    one_line_error(code, text, err, "the results folder", "cannot be made", "choose another --out")
