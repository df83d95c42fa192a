"""A finished run extended to more steps (`dgtd run --resume DIR -T LARGER`, `dgtd.run.extend`): the state kept at
its end goes on to the numbers of a run of the new length from its start, where that state allows; elsewhere one
line says why."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_checkpoint import assert_same_run

from dgtd.config import make_channel, resolve, unflat
from dgtd.run.loop import run as run_loop
from dgtd.run.settings import checkpoint_steps, tail_blocker

SAME = ("w_last", "w_avg", "w_tail")


def _pieces(iterations: int, **more):
    spec = unflat(
        dict(scenario="paper-example-1", iterations=iterations, seeds=2, reward_noise="bernoulli", edge_prob=0.7,
             checkpoints=12, block_size=300, **more)
    )  # fmt: skip
    problem, network, algorithm, samp, settings, resolved, _ = resolve(spec)
    return (problem, network, algorithm, samp, settings), make_channel(resolved, network)


@pytest.mark.parametrize("backend", ["numpy", "numba"])
@pytest.mark.parametrize("loss", [None, 0.3])
def test_a_finished_run_extended_equals_a_run_of_the_new_length(backend, loss):
    short, channel = _pieces(1000, backend=backend, loss=loss, sampling="markov")
    long, _ = _pieces(2600, backend=backend, loss=loss, sampling="markov")
    snaps: list = []
    first = run_loop(*short, channel=channel, checkpoint_every=400, on_checkpoint=snaps.append)
    assert [s["k"] for s in snaps] == [400, 800, 1000]  # the state at T is kept too
    whole = run_loop(*long, channel=channel)
    extended = run_loop(*long, channel=channel, resume=snaps[-1])
    for name in SAME:
        np.testing.assert_array_equal(getattr(extended, name), getattr(whole, name), err_msg=name)
    for name in whole.final_state:
        np.testing.assert_array_equal(extended.final_state[name], whole.final_state[name], err_msg=name)
    np.testing.assert_array_equal(extended.info["messages"], whole.info["messages"])
    # the checkpoints measured are kept, and a run of 2 600 steps' follow
    grid = checkpoint_steps(2600, 12)
    np.testing.assert_array_equal(extended.steps, np.concatenate([first.steps, grid[grid > 1000]]))
    for name, values in first.metrics.items():
        np.testing.assert_array_equal(extended.metrics[name][: len(first.steps)], values, err_msg=name)
    later = np.isin(whole.steps, extended.steps) & (whole.steps > 1000)
    mine = np.isin(extended.steps, whole.steps[later])
    for name in ("error_last", "value_error_last", "consensus", "error_avg"):  # (not the tails': their grids differ)
        np.testing.assert_array_equal(extended.metrics[name][mine], whole.metrics[name][later], err_msg=name)


def test_an_extension_cut_off_resumes_to_the_uninterrupted_extension():
    short, channel = _pieces(1000, backend="numpy")
    long, _ = _pieces(3000, backend="numpy")
    snaps: list = []
    run_loop(*short, channel=channel, checkpoint_every=500, on_checkpoint=snaps.append)
    on: list = []
    extended = run_loop(*long, channel=channel, resume=snaps[-1], checkpoint_every=500, on_checkpoint=on.append)
    assert [s["k"] for s in on] == [1500, 2000, 2500, 3000]
    assert_same_run(extended, run_loop(*long, channel=channel, resume=on[1]))


def test_a_tail_of_the_whole_run_extends_too():
    """With --tail-fraction 1 the tail begins at step 0 for any length: its base is kept."""
    short, channel = _pieces(800, backend="numpy", tail_fraction=1.0)
    long, _ = _pieces(1700, backend="numpy", tail_fraction=1.0)
    snaps: list = []
    run_loop(*short, channel=channel, checkpoint_every=800, on_checkpoint=snaps.append)
    whole, extended = run_loop(*long, channel=channel), run_loop(*long, channel=channel, resume=snaps[-1])
    for name in SAME:
        np.testing.assert_array_equal(getattr(extended, name), getattr(whole, name), err_msg=name)


def test_the_tail_rule_names_the_least_steps():
    assert tail_blocker(2000, 4000, 0.5) == "" and tail_blocker(2000, 3000, 0.3) == ""
    why = tail_blocker(2000, 3000, 0.5)
    assert "begin at step 1,500" in why and "give -T 4000 or more" in why
    assert "give -T 2858 or more" in tail_blocker(2000, 2100, 0.3)  # (2858 - ceil(857.4) = 2000; 2857 - 858 < 2000)
    assert tail_blocker(2000, 2100, 1.0) == ""


def _cli_run(run_cli, out, *more):
    args = ("run", "paper-example-1", "--backend", "numpy", "--no-plots", "--no-progress", "--out", out, *more)
    return run_cli(*args)


def test_dgtd_run_resume_with_a_larger_T_extends_the_finished_run(tmp_path, run_cli):
    """The finding: a finished run could not be extended (a larger -T was ignored: 'already finished')."""
    out, whole = tmp_path / "ext", tmp_path / "whole"
    code, _, err = _cli_run(run_cli, out, "-T", "2000", "--checkpoint-every", "500")
    assert code == 0 and (out / "checkpoint.npz").exists(), err  # the state at T stays
    code, text, err = run_cli("run", "--resume", out, "-T", "4000")
    assert code == 0 and "extending the finished run" in text and "from 2,000 to 4,000 steps" in text, err
    code, _, err = _cli_run(run_cli, whole, "-T", "4000", "--checkpoint-every", "500")
    assert code == 0, err
    a, b = (json.loads((d / "summary.json").read_text()) for d in (out, whole))
    a.pop("seconds"), b.pop("seconds")
    assert a == b  # iterates, averages, tail, errors, counts and the config (-T 4000) alike
    assert "iterations = 4000" in (out / "config.toml").read_text()
    code, text, _ = run_cli("run", "--resume", out)
    assert code == 0 and "already finished" in text


def test_what_cannot_extend_a_run_is_one_line(tmp_path, run_cli):
    out, stateless = tmp_path / "ext", tmp_path / "stateless"
    assert _cli_run(run_cli, out, "-T", "2000", "--checkpoint-every", "500")[0] == 0
    cases = {
        ("-T", "3000"): "would begin at step 1,500, before its end",
        ("-T", "1000"): "took 2,000 steps already; -T 1,000 would go back",
        ("-T", "4000", "--kappa", "3"): "extended by -T alone; kappa = 1.0 there, 3.0 here",
    }
    for args, says in cases.items():
        code, _, err = run_cli("run", "--resume", out, *args)
        assert code == 2 and says in err and len(err.strip().splitlines()) == 1, (args, err)
    code, _, err = _cli_run(run_cli, out, "-T", "4000", "--checkpoint-every", "500")  # (without --resume)
    assert code == 2 and f"extend it with `dgtd run --resume {out} -T 4000`" in err
    assert _cli_run(run_cli, stateless, "-T", "2000")[0] == 0
    assert not (stateless / "checkpoint.npz").exists()
    code, _, err = run_cli("run", "--resume", stateless, "-T", "4000")
    assert code == 2 and "without keeping its state" in err and "--checkpoint-every" in err
    code, _, err = _cli_run(run_cli, out, "-T", "2000", "--checkpoint-every", "500")  # the same command again
    assert code == 0 and "resuming" not in err  # redoes the run, as before


def _cli_learn(run_cli, out, *more):
    args = ("learn", "pull-away", "--loss", "0.2", "--no-plots", "--no-progress", "--out", out, *more)
    return run_cli(*args)


def test_dgtd_learn_resume_with_a_larger_T_extends_the_finished_learning_run(tmp_path, run_cli):
    """The same for learners: the state kept at the end goes on to a run of the new length's numbers, where the
    actor's steps so far are that run's (a warm-up given, or of 2 000 steps: runs of 20 000 and more)."""
    out, whole = tmp_path / "ext", tmp_path / "whole"
    assert _cli_learn(run_cli, out, "-T", "1200", "--actor-warmup", "100", "--checkpoint-every", "400")[0] == 0
    assert (out / "learning-checkpoint.npz").exists()
    code, text, err = run_cli("learn", "--resume", out, "-T", "2000", "--no-plots", "--no-progress")
    assert code == 0 and "extending the finished learning run" in text and "from 1,200 to 2,000 steps" in text, err
    assert _cli_learn(run_cli, whole, "-T", "2000", "--actor-warmup", "100", "--checkpoint-every", "400")[0] == 0
    a, b = (json.loads((d / "summary.json").read_text()) for d in (out, whole))
    a.pop("seconds"), b.pop("seconds")
    assert a == b  # the policies, their exact J, the critics, the counts and the config (-T 2000) alike
    later = {line for line in _rows(out) if int(line.split(",")[2]) > 1200}
    assert later and later <= _rows(whole)  # the metrics beyond its end a run of 2 000 steps' (on its grid)
    assert "iterations = 2000" in (out / "config.toml").read_text()
    code, text, _ = run_cli("learn", "--resume", out, "--no-progress")
    assert code == 0 and "already finished" in text


def _rows(folder) -> set:
    return set((folder / "metrics.csv").read_text().splitlines()[1:])


def test_what_cannot_extend_a_learning_run_is_one_line(tmp_path, run_cli):
    out, stateless = tmp_path / "ext", tmp_path / "stateless"
    assert _cli_learn(run_cli, out, "-T", "1200", "--checkpoint-every", "400")[0] == 0
    code, _, err = run_cli("learn", "--resume", out, "-T", "3000")
    assert code == 2 and "holds still" in err and "120 steps in this run and 300 in one of 3,000" in err, err
    code, _, err = run_cli("learn", "--resume", out, "-T", "800")
    assert code == 2 and "took 1,200 steps already" in err, err
    code, _, err = _cli_learn(run_cli, out, "-T", "3000", "--checkpoint-every", "400")  # (without --resume)
    assert code == 2 and f"extend it with `dgtd learn --resume {out} -T 3000`" in err, err
    assert _cli_learn(run_cli, stateless, "-T", "600")[0] == 0
    assert not (stateless / "learning-checkpoint.npz").exists()
    code, _, err = run_cli("learn", "--resume", stateless, "-T", "900")
    assert code == 2 and "without keeping its state" in err and len(err.strip().splitlines()) == 1, err
