"""A learned policy can be used (issue: close the loop): `dgtd run --problem FILE --policies DIR` evaluates a learning
run's last policies with any distributed critic, and `dgtd learn --from DIR` starts learners from them."""

from __future__ import annotations

import json

import numpy as np
import pytest

from dgtd.problems import team
from tests.helpers import one_line_error


def pull_away_file(path) -> str:
    """pull-away as a multi-agent MDP file, uniform starting policies."""
    mdp = team.pull_away()
    uniform = {f"policy_{i}": np.full((3, 2), 0.5) for i in range(4)}
    np.savez(path, P=mdp.P, R=mdp.R, Phi=mdp.Phi, gamma=mdp.gamma, **uniform)
    return str(path)


@pytest.fixture(scope="module")
def learnt(tmp_path_factory):
    """A 3 000-step learning run on the file, 2 seeds."""
    from dgtd.cli import main

    folder = tmp_path_factory.mktemp("loop")
    file = pull_away_file(folder / "team.npz")
    try:
        main(["learn", "--problem", file, "-T", "3000", "--no-progress", "--no-plots", "--out", str(folder / "L")])
    except SystemExit as done:
        assert done.code in (0, None)
    return file, folder / "L", json.loads((folder / "L" / "summary.json").read_text())


@pytest.mark.parametrize("seed", [0, 1])
def test_a_learning_runs_policies_are_evaluated_by_dgtd_run(run_cli, tmp_path, learnt, seed):
    """The run's exact w* is the learned policies' value: its d-weighted mean is J / (1 - gamma), J the learning
    run's exact long-run average of seed ``seed``'s policies (summary.json return_last), to 1e-10 (d^T V = d^T r /
    (1 - gamma) for V = (I - gamma P)^-1 r and d stationary); DGTD's tail-averaged estimates reach it within 1 %."""
    file, L, learned = learnt
    code, out, err = run_cli("run", "--problem", file, "--policies", L, "--policies-seed", seed, "-T", 30000,
                             "--no-progress", "--no-plots", "--out", tmp_path / "R")  # fmt: skip
    assert code == 0, err
    summary = json.loads((tmp_path / "R" / "summary.json").read_text())
    mdp = team.pull_away()
    policies = [np.asarray(p) for p in learned["policy_last"][seed]]
    d = team.long_run(mdp.chain(policies)[0], mdp.start)
    w_star = np.asarray(summary["w_star"])
    assert d @ mdp.Phi @ w_star == pytest.approx(learned["return_last"][seed] / (1 - mdp.gamma), abs=1e-10)
    tail = np.asarray(summary["w_tail"])  # (agents, q) of seed 0
    assert np.abs(tail - w_star).max() / np.abs(w_star).max() < 0.01
    assert "policies" in (tmp_path / "R" / "config.toml").read_text()


def test_learners_start_from_a_learning_runs_policies(run_cli, tmp_path, learnt):
    """`dgtd learn --from DIR`: while the actors hold still (the warm-up: a tenth of 100 steps) the exact return is
    that of the earlier run's last policies, each probability floored at 1e-6 (within 1e-4)."""
    file, L, learned = learnt
    code, _, err = run_cli("learn", "--problem", file, "--from", L, "--from-seed", 1, "-T", 100, "--checkpoints", 10,
                           "--no-progress", "--no-plots", "--out", tmp_path / "F")  # fmt: skip
    assert code == 0, err
    rows = [line.split(",") for line in (tmp_path / "F" / "metrics.csv").read_text().splitlines()[1:]]
    first = [float(r[4]) for r in rows if r[3] == "return" and r[2] == "10"]
    assert first and max(abs(J - learned["return_last"][1]) for J in first) < 1e-4


@pytest.mark.parametrize(
    "args, words",
    [
        (["run", "paper-example-1", "--policies", "{L}"], ["--problem"]),
        (["run", "--problem", "{other}", "--policies", "{L}"], ["policies given are 4 agents'"]),
        (["run", "--problem", "{file}", "--policies", "{L}", "--policies-seed", "7"], ["not of seed 7"]),
        (["run", "--problem", "{file}", "--policies", "{missing}"], ["policies"]),
        (["learn", "zhang-20", "--from", "{L}"], ["another task"]),
        (["learn", "pull-away", "--from-seed", "1"], ["--from DIR"]),
        (["learn", "mpe-spread", "--from", "{L}"], ["linear in its observations"]),
        (["learn", "pull-away", "--from", "{L}", "--from-seed", "-1"], ["from_seed"]),
    ],
)
def test_bad_learned_policy_input_is_one_line(run_cli, tmp_path, learnt, args, words):
    file, L, _ = learnt
    other = tmp_path / "other.npz"
    m = team.pull_away(3, 3)
    np.savez(other, P=m.P, R=m.R, Phi=m.Phi, gamma=m.gamma, **{f"policy_{i}": np.full((3, 2), 0.5) for i in range(3)})
    names = {"L": str(L), "other": str(other), "file": file, "missing": str(tmp_path / "nowhere")}
    given = [a.format(**names) for a in args]
    one_line_error(*run_cli(*given, "-T", 10, "--no-progress", "--out", tmp_path / "o"), *words)


def test_ctrl_c_during_a_learning_run_keeps_the_metrics_measured_so_far(run_cli, tmp_path, monkeypatch):
    """A learning run without --checkpoint-every kept nothing when interrupted: metrics.csv now holds every checkpoint
    measured before Ctrl-C, each row the uninterrupted run's."""
    import dgtd.run.learn as learning

    command = ("learn", "pull-away", "-T", 1000, "--checkpoints", 10, "--no-progress", "--no-plots")
    code, _, err = run_cli(*command, "--out", tmp_path / "whole")
    assert code == 0, err
    measure, seen = learning.measure, []

    def interrupted_at_the_sixth(*args):
        if len(seen) == 6:
            raise KeyboardInterrupt
        seen.append(1)
        measure(*args)

    monkeypatch.setattr(learning, "measure", interrupted_at_the_sixth)
    code, _, err = run_cli(*command, "--out", tmp_path / "cut")
    assert code == 130, err
    whole, cut = ((tmp_path / d / "metrics.csv").read_text().splitlines() for d in ("whole", "cut"))
    steps = sorted({int(row.split(",")[2]) for row in whole[1:]})
    assert cut[0] == whole[0] and set(cut[1:]) <= set(whole[1:])
    assert sorted({int(row.split(",")[2]) for row in cut[1:]}) == steps[:6]
    assert not (tmp_path / "cut" / "summary.json").exists()
