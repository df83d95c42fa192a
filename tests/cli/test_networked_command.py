"""`dgtd networked TASK` and `dgtd compare TASK` on networked systems (`dgtd.cli.networked`)."""

from __future__ import annotations

import json
import tomllib

import numpy as np
import pytest
from helpers import one_line_error

SHORT = ("-T", 200, "--every", 100, "--rollouts", 20, "--no-progress", "--no-plots")


def test_a_networked_run_writes_its_numbers(run_cli, tmp_path):
    out = tmp_path / "w"
    code, text, err = run_cli("networked", "wireless-access", *SHORT, "--seeds", 2, "--out", out)
    assert code == 0, err
    assert "24 agents" in text and "heuristic (best of 20)" in text
    summary = json.loads((out / "summary.json").read_text())
    run = summary["learners"]["scalable"]
    assert run["episodes"] == [0, 100, 200] and np.shape(run["return"]) == (3, 2)
    assert 0.01 < run["return"][0][0] < 0.035  # uniform policies: 0.020 (20 rollouts here)
    assert 0.1 < summary["heuristic"]["return"][0] < 0.3 and summary["heuristic"]["of"] == 20
    rows = (out / "metrics.csv").read_text().splitlines()
    assert rows[0] == "learner,seed,episode,metric,value" and len(rows) == 1 + 3 * 2
    values = [float(row.split(",")[-1]) for row in rows[1:]]  # (numbers: it wrote NumPy's repr, np.float64(...))
    assert values == [v for c in run["return"] for v in c]
    with np.load(out / "policies.npz") as p:
        assert p["policies"].shape == (2, 24, 4, 9)
    saved = tomllib.loads((out / "config.toml").read_text())["networked"]
    assert saved["task"] == "wireless-access" and saved["episodes"] == 200 and saved["hops"] == 1


def test_the_comparison_runs_each_learner_on_the_same_numbers(run_cli, tmp_path, few_rollouts):
    """The networked learners of `dgtd compare` are `dgtd networked`'s run at the same options, to the bit; the
    independent ones start from the same uniform return (the same rollouts)."""
    code, _, err = run_cli("compare", "random-networked", "-T", 150, "--seeds", 2, "--no-progress", "--no-plots",
                           "--out", tmp_path / "c")  # fmt: skip
    assert code == 0, err
    both = json.loads((tmp_path / "c" / "summary.json").read_text())["learners"]
    assert set(both) == {"networked (kappa 1)", "independent (kappa 0)"}
    one = both["networked (kappa 1)"]
    code, _, err = run_cli("networked", "random-networked", "-T", 150, "--seeds", 2, "--every", 2000,
                           "--rollouts", 10, "--no-progress", "--no-plots", "--out", tmp_path / "n")  # fmt: skip
    assert code == 0, err
    alone = json.loads((tmp_path / "n" / "summary.json").read_text())["learners"]["scalable"]
    assert alone["return"] == one["return"]
    assert both["independent (kappa 0)"]["return"][0] == one["return"][0]


@pytest.mark.parametrize(
    "args, says",
    [
        (("networked", "foo"), "name a networked task: wireless-access, random-networked, epidemic; got 'foo'"),
        (("networked",), "name a networked task"),
        (("networked", "wireless-access", "--agents", 25), "a multiple of 6 from 12 (e.g. 30); got 25"),
        (("networked", "random-networked", "--agents", 2), "--agents 3 or more"),
        (("networked", "wireless-access", "--hops", -1), "hops must be >= 0"),
        (("networked", "wireless-access", "-T", 0), "episodes must be >= 1"),
        (("networked", "wireless-access", "--critic-power", 0), "steps, offset and power must be numbers > 0"),
        (("compare", "wireless-access", "--loss", 0.2), "takes -T, --seeds and --agents; --loss"),
        (("learn", "wireless-access"), "is a networked system, agents with local states: `dgtd networked"),
    ],
)
def test_bad_input_is_one_line(run_cli, tmp_path, args, says):
    one_line_error(*run_cli(*args, "--out", tmp_path / "x"), says)


def test_a_run_cut_off_keeps_its_evaluations(run_cli, tmp_path, monkeypatch):
    """Ctrl-C after the second evaluation (episode 100): metrics.csv holds the start's and that one's rows."""
    import dgtd.cli.networked as cli_networked

    calls, write = [], cli_networked._metrics

    def cut(out, results):
        write(out, results)
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt

    monkeypatch.setattr(cli_networked, "_metrics", cut)
    code, _, err = run_cli("networked", "random-networked", *SHORT, "--out", tmp_path / "cut")
    assert code == 130 and "interrupted" in err
    rows = (tmp_path / "cut" / "metrics.csv").read_text().splitlines()[1:]
    assert [row.split(",")[2] for row in rows] == ["0", "100"]
    assert not (tmp_path / "cut" / "summary.json").exists()


def _save(path, **arrays):
    np.savez(path, **arrays)
    return path


def test_a_networked_mdp_file_learns_as_the_same_task_named(run_cli, tmp_path):
    """A file holding random-networked's arrays (a ring of 10) gives `dgtd networked random-networked`'s numbers."""
    from dgtd.graphs import topologies
    from dgtd.problems.networked import random_networked

    mdp = random_networked(topologies.ring(10).edges, 10, gamma=0.7)
    path = _save(tmp_path / "ring.npz", edges=topologies.ring(10).edges, P=mdp.P, R=mdp.R, gamma=0.7, start=mdp.start)
    runs = {}
    for name, given in {"file": ("--problem", path), "named": ("random-networked",)}.items():
        code, text, err = run_cli("networked", *given, *SHORT, "--out", tmp_path / name)
        assert code == 0, err
        runs[name] = json.loads((tmp_path / name / "summary.json").read_text())
    assert runs["file"]["learners"]["scalable"]["return"] == runs["named"]["learners"]["scalable"]["return"]
    assert len(runs["file"]["config"]["problem_sha256"]) == 64


def test_a_bad_networked_mdp_file_is_one_line(run_cli, tmp_path):
    from dgtd.graphs import topologies
    from dgtd.problems.networked import random_networked

    mdp = random_networked(topologies.ring(4).edges, 4, gamma=0.7)
    good = dict(edges=topologies.ring(4).edges, P=mdp.P, R=mdp.R, gamma=0.7)
    nan = mdp.P.copy()
    nan[0, 0, 0, 0] = np.nan
    cases = {
        "lacks": ({k: v for k, v in good.items() if k != "P"}, "lacks P"),
        "nan": ({**good, "P": nan}, "is a probability distribution"),
        "shape": ({**good, "P": mdp.P[:, :4]}, "needs P (N, S^K, A, S)"),
        "edges": ({**good, "edges": np.array([[0, 7]])}, "edges name agents 0 .. 3 (R has 4); got 0 .. 7"),
        "gamma": ({**good, "gamma": np.array([0.5, 0.5])}, "gamma must be one number"),
        "discount": ({**good, "gamma": 1.0}, "gamma must be in [0, 1)"),
    }
    for name, (arrays, says) in cases.items():
        path = _save(tmp_path / f"{name}.npz", **arrays)
        one_line_error(*run_cli("networked", "--problem", path, "--out", tmp_path / name), says)
    path = _save(tmp_path / "ok.npz", **good)
    one_line_error(*run_cli("networked", "epidemic", "--problem", path, "--out", tmp_path / "x"), "one of them")
    one_line_error(*run_cli("networked", "--problem", path, "--agents", 8, "--out", tmp_path / "y"), "--agents sizes")


def test_a_run_cut_off_after_a_checkpoint_continues_to_the_uninterrupted_numbers(run_cli, tmp_path, monkeypatch):
    import dgtd.cli.networked as cli_networked
    from dgtd.run import checkpoint

    command = ("networked", "random-networked", "-T", 300, "--every", 100, "--rollouts", 10, "--no-progress",
               "--no-plots", "--checkpoint-every", 100)  # fmt: skip
    assert run_cli(*command, "--out", tmp_path / "whole")[0] == 0
    save = checkpoint.save_checkpoint

    def cut(path, snapshot, record):
        save(path, snapshot, record)
        raise KeyboardInterrupt

    monkeypatch.setattr(checkpoint, "save_checkpoint", cut)
    assert run_cli(*command, "--out", tmp_path / "cut")[0] == 130
    monkeypatch.setattr(checkpoint, "save_checkpoint", save)
    assert (tmp_path / "cut" / "checkpoint.npz").exists()
    one_line_error(*run_cli(*command, "--seed", 3, "--out", tmp_path / "cut"), "checkpoint of another")
    code, text, err = run_cli(*command, "--out", tmp_path / "cut")
    assert code == 0 and "resuming" in text and "episode 100" in text, err
    a, b = (json.loads((tmp_path / d / "summary.json").read_text()) for d in ("whole", "cut"))
    assert a["learners"]["scalable"]["return"] == b["learners"]["scalable"]["return"]
    assert (tmp_path / "cut" / "metrics.csv").read_text() == (tmp_path / "whole" / "metrics.csv").read_text()
    assert not (tmp_path / "cut" / "checkpoint.npz").exists()
    assert cli_networked.CHECKPOINT == "checkpoint.npz"


def test_a_networked_folder_is_known_for_what_it_holds(run_cli, tmp_path, few_rollouts):
    """Run or compare again into their own folder: redone; another command's writer is refused in one line."""
    compare = ("compare", "random-networked", "-T", 20, "--seeds", 1, "--no-progress", "--no-plots")
    for _ in range(2):
        code, _, err = run_cli(*compare, "--out", tmp_path / "c")
        assert code == 0, err
    for _ in range(2):
        code, _, err = run_cli("networked", "random-networked", *SHORT, "--out", tmp_path / "n")
        assert code == 0, err
    one_line_error(*run_cli("run", "paper-example-1", "--out", tmp_path / "n"), "holds the results of a learning run")
    one_line_error(*run_cli("networked", "random-networked", *SHORT, "--out", tmp_path / "c"), "of a comparison")
