"""Long runs resume: a run continued from a checkpoint ends with exactly the numbers of an uninterrupted run."""

from __future__ import annotations

import functools
import json
import signal
import subprocess
import time

import numpy as np
import pytest
from conftest import cli_env, dgtd_cmd

from dgtd.config import make_channel, resolve, unflat
from dgtd.run.checkpoint import load_checkpoint, save_checkpoint
from dgtd.run.loop import run
from dgtd.run.loop import run as run_loop

ARRAYS = ("w_last", "w_avg", "w_tail", "agent_error_last", "agent_error_avg", "w_trace", "steps")


def assert_same_run(a, b):
    for name in ARRAYS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    for name in a.metrics:
        np.testing.assert_array_equal(a.metrics[name], b.metrics[name], err_msg=name)
    for name in a.final_state:
        np.testing.assert_array_equal(a.final_state[name], b.final_state[name], err_msg=name)
    for name in a.info["counts"]:  # the channel's counts, which the checkpoint carries with its state
        np.testing.assert_array_equal(a.info["counts"][name], b.info["counts"][name], err_msg=name)
    np.testing.assert_array_equal(a.info["messages"], b.info["messages"])
    np.testing.assert_array_equal(a.info["bits"], b.info["bits"])
    for name in a.info.get("per_agent", {}):
        np.testing.assert_array_equal(a.info["per_agent"][name], b.info["per_agent"][name])


@pytest.mark.parametrize("backend", ["numpy", "numba"])
@pytest.mark.parametrize("sampling", ["iid", "markov"])
@pytest.mark.parametrize(
    "loss, burst, links",
    [
        (None, None, {}),
        (0.3, None, {}),
        (0.3, 5.0, {}),
        (0.3, None, dict(delay=3, wake=0.7, bits=3)),  # copies, messages in flight and the step carried
        pytest.param(None, None, dict(bits=2, error_feedback=True, top_k=1), marks=pytest.mark.slow),
    ],
)
def test_resume_from_any_checkpoint_is_bit_for_bit(tmp_path, backend, sampling, loss, burst, links):
    # random edges, reward noise, Markov states and lost messages: every stream and the trajectories' current states
    spec = unflat(
        dict(
            scenario="paper-example-1",
            iterations=2500,
            seeds=3,
            backend=backend,
            sampling=sampling,
            reward_noise="bernoulli",
            edge_prob=0.7,
            loss=loss,
            burst=burst,
            **links,
            checkpoints=15,
            block_size=300,
        )
    )
    problem, network, algorithm, samp, settings, resolved, channel = resolve(spec)
    channel = make_channel(resolved, network)
    run = functools.partial(run_loop, channel=channel)
    whole = run(problem, network, algorithm, samp, settings)
    snaps = []
    saving = run(problem, network, algorithm, samp, settings, checkpoint_every=600, on_checkpoint=snaps.append)
    assert [s["k"] for s in snaps] == [600, 1200, 1800, 2400, 2500]  # (and at T: a finished run extends)
    assert_same_run(whole, saving)  # checkpointing (and the block boundaries it adds) changes nothing
    for i in (0, 3):  # through the file format, from the first and the last checkpoint
        save_checkpoint(tmp_path / "c.npz", snaps[i], {"spec": "x"})
        snap, config = load_checkpoint(tmp_path / "c.npz")
        assert config == {"spec": "x"}
        assert_same_run(whole, run(problem, network, algorithm, samp, settings, resume=snap))


def test_a_killed_run_resumes_to_the_same_files(tmp_path):
    """Kill `dgtd run --checkpoint-every` after a checkpoint, `--resume` it, and compare with a whole run."""
    exp = tmp_path / "long.toml"
    exp.write_text(
        'scenario = "paper-example-1"\niterations = 400000\nseeds = 2\nbackend = "numba"\n'
        'reward_noise = "uniform"\ncheckpoints = 40\nplots = false\nprogress = false\n'
    )
    whole = subprocess.run(
        dgtd_cmd("run", exp, "--out", tmp_path / "whole"), env=cli_env(), capture_output=True, text=True
    )
    assert whole.returncode == 0, whole.stderr
    out = tmp_path / "cut"
    proc = subprocess.Popen(
        dgtd_cmd("run", exp, "--out", out, "--checkpoint-every", "20000"),
        env=cli_env(),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.time() + 120
    while not (out / "checkpoint.npz").exists() and proc.poll() is None and time.time() < deadline:
        time.sleep(0.05)
    time.sleep(0.1)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not (out / "summary.json").exists(), "the run finished before it could be killed; make it longer"
    snap, _ = load_checkpoint(out / "checkpoint.npz")
    assert 0 < snap["k"] < 400_000
    resumed = subprocess.run(dgtd_cmd("run", "--resume", out), env=cli_env(), capture_output=True, text=True)
    assert resumed.returncode == 0, resumed.stderr
    assert "resuming" in resumed.stdout
    assert (out / "metrics.csv").read_bytes() == (tmp_path / "whole" / "metrics.csv").read_bytes()
    a, b = (json.loads((d / "summary.json").read_text()) for d in (out, tmp_path / "whole"))
    a.pop("seconds"), b.pop("seconds")
    assert a == b
    with np.load(out / "trajectory.npz") as x, np.load(tmp_path / "whole" / "trajectory.npz") as y:
        for k in y.files:
            np.testing.assert_array_equal(x[k], y[k])
    assert load_checkpoint(out / "checkpoint.npz")[0]["k"] == 400_000  # the state at its end stays, to extend it
    again = subprocess.run(dgtd_cmd("run", "--resume", out), env=cli_env(), capture_output=True, text=True)
    assert again.returncode == 0 and "already finished" in again.stdout


def test_resume_refuses_another_config(tmp_path, run_cli):
    out = tmp_path / "r"
    code, _, err = run_cli(
        "run",
        "paper-example-1",
        "-T",
        "2000",
        "--backend",
        "numpy",
        "--no-plots",
        "--no-progress",
        "--checkpoints",
        "5",
        "--out",
        out,
        "--checkpoint-every",
        "500",
    )
    assert code == 0, err
    # leave a checkpoint behind as a killed run would
    problem, network, algorithm, samp, settings, resolved, channel = resolve(
        unflat(dict(scenario="paper-example-1", iterations=2000, backend="numpy", checkpoints=5))
    )
    snaps = []
    run(problem, network, algorithm, samp, settings, checkpoint_every=500, on_checkpoint=snaps.append)
    from dgtd.config import spec_record

    save_checkpoint(out / "checkpoint.npz", snaps[0], json.loads(json.dumps(spec_record(resolved))))
    code, _, err = run_cli("run", "--resume", out, "--kappa", "3")
    assert code == 2 and "checkpoint" in err and "kappa = 1.0 there, 3.0 here" in err, err
    code, out_text, err = run_cli("run", "--resume", out)
    assert code == 0 and "resuming" in out_text, err
    code, _, err = run_cli("run", "--resume", tmp_path / "nothing")
    assert code == 2 and "is not a directory" in err


def _rewritten(path, old, snap):
    """Checkpoint ``path`` of ``snap`` as file format ``old`` wrote it."""
    import io

    save_checkpoint(path, snap, {"spec": "x"})
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(str(arrays.pop("__meta__")))
    assert meta["written_by"].startswith("dgtd ")
    meta["format"] = old
    if old < 4:
        del meta["written_by"]  # as the older formats were written
    buf = io.BytesIO()
    np.savez(buf, __meta__=np.array(json.dumps(meta)), **arrays)
    path.write_bytes(buf.getvalue())


@pytest.mark.parametrize("old", [1, 2, 3])
def test_checkpoint_of_another_format_is_refused(tmp_path, old):
    """A checkpoint written by another file format (1 kept a second running sum for the tail average, 2 no channel
    state, 3 sequential random streams' states) is refused with one line that says which dgtd wrote it, not
    misread."""
    from dgtd.errors import DgtdInputError
    from dgtd.run import checkpoint

    path = tmp_path / "c.npz"
    _rewritten(path, old, {"k": 1, "sums": {"all": np.zeros(3)}})
    assert checkpoint.FORMAT == 5
    who = "with sequential random streams" if old == 3 else "before the channels"
    with pytest.raises(DgtdInputError, match=f"written by dgtd {who} \\(format {old}\\); this dgtd \\(format 5, keyed"):
        load_checkpoint(path)


def test_a_format_4_checkpoint_continues_unless_messages_are_in_flight(tmp_path):
    """Format 4 kept late messages in the slot of the step they were sent at, 5 in that of the step they arrive at:
    a format-4 checkpoint of a run without --delay reads as before, one with messages in flight is refused."""
    from dgtd.errors import DgtdInputError

    path = tmp_path / "c.npz"
    _rewritten(path, 4, {"k": 1, "sums": {"all": np.zeros(3)}, "channel": {"pending": np.zeros((1, 2, 0, 0))}})
    assert load_checkpoint(path)[0]["k"] == 1
    _rewritten(path, 4, {"k": 1, "sums": {"all": np.zeros(3)}, "channel": {"pending": np.zeros((1, 2, 3, 1))}})
    with pytest.raises(DgtdInputError, match="format 4.*late messages by arrival"):
        load_checkpoint(path)


def test_the_same_command_again_resumes_its_checkpoint(tmp_path, run_cli):
    """A run cut off after a checkpoint continues when the same command is given again (no --resume needed), and ends
    with the uninterrupted numbers; a checkpoint of another config is not thrown away without --overwrite."""
    command = ("run", "paper-example-1", "-T", "2000", "--backend", "numpy", "--no-plots", "--no-progress")
    command += ("--checkpoints", "5", "--checkpoint-every", "500")
    code, _, err = run_cli(*command, "--out", tmp_path / "whole")
    assert code == 0, err
    out = tmp_path / "cut"
    problem, network, algorithm, samp, settings, resolved, channel = resolve(
        unflat(dict(scenario="paper-example-1", iterations=2000, backend="numpy", checkpoints=5))
    )
    snaps = []
    run(problem, network, algorithm, samp, settings, checkpoint_every=500, on_checkpoint=snaps.append)
    from dgtd.config import spec_record

    code, _, err = run_cli(*command, "-T", "1", "--out", out)  # the directory and its config.toml, as a run leaves them
    assert code == 0, err
    (out / "summary.json").unlink()
    save_checkpoint(out / "checkpoint.npz", snaps[1], json.loads(json.dumps(spec_record(resolved))))
    code, _, err = run_cli(*command, "--kappa", "3", "--out", out)
    assert code == 2 and "checkpoint of another run" in err and "kappa = 1.0 there, 3.0 here" in err, err
    assert (out / "checkpoint.npz").exists()
    code, said, err = run_cli(*command, "--out", out)
    assert code == 0 and "resuming" in said and "1,000" in said, err
    assert (out / "metrics.csv").read_bytes() == (tmp_path / "whole" / "metrics.csv").read_bytes()
    save_checkpoint(out / "checkpoint.npz", snaps[1], json.loads(json.dumps(spec_record(resolved))))
    code, said, err = run_cli(*command, "--overwrite", "--out", out)  # --overwrite starts afresh
    assert code == 0 and "resuming" not in said, err
    assert load_checkpoint(out / "checkpoint.npz")[0]["k"] == 2000  # (the state at its end)


def test_a_problem_file_changed_under_a_checkpoint_is_said_so_by_every_command_that_meets_it(tmp_path, run_cli):
    """The problem file changed since the checkpoint was written: the same command, --resume and the run's own
    config.toml each say that the file changed and how to go on (restore it, or --overwrite), instead of sending
    the user from one to the next in a circle; --overwrite then runs."""
    problem = tmp_path / "chain.npz"
    np.savez(problem, P=np.array([[0.3, 0.7], [0.6, 0.4]]), R=np.eye(2), Phi=np.array([[1.0], [0.5]]), gamma=0.9)
    out = tmp_path / "run"
    command = ("run", "--problem", problem, "-T", "50", "--no-plots", "--no-progress", "--out", out)
    code, _, err = run_cli(*command)
    assert code == 0, err
    record = json.loads((out / "summary.json").read_text())["config"]
    (out / "summary.json").unlink()
    save_checkpoint(out / "checkpoint.npz", {"k": 25}, {**record, "problem_sha256": "0" * 64})  # as the file was
    for again in (command, ("run", "--resume", out), ("run", out / "config.toml")):
        code, said, err = run_cli(*again)
        assert code == 2 and f"the problem file {problem} changed since the checkpoint" in err, err
        assert "--overwrite" in err and "--resume" not in err and "config.toml" not in err, err
    code, _, err = run_cli(*command, "--overwrite")
    assert code == 0, err


@pytest.mark.parametrize("role", ["graph", "loss"])
def test_a_graph_or_loss_file_changed_under_a_checkpoint_is_refused_naming_it(tmp_path, run_cli, role):
    """A graph's edge list or a loss file that changed since the checkpoint (the same path) would continue the run on
    another network: the same command and --resume say which file changed and how to go on, and --overwrite runs."""
    graph, loss = tmp_path / "g.txt", tmp_path / "loss.txt"
    graph.write_text("0 1\n1 2\n2 3\n3 4\n4 0\n")
    loss.write_text("0 1 0.2\n")
    out = tmp_path / "run"
    command = ("run", "paper-example-1", "--graph", graph, "--loss", loss, "-T", "50", "--no-plots", "--no-progress")
    command += ("--out", out, "--backend", "numpy")
    code, _, err = run_cli(*command)
    assert code == 0, err
    record = json.loads((out / "summary.json").read_text())["config"]
    assert len(record["graph_sha256"]) == 64 and len(record["loss_sha256"]) == 64
    (out / "summary.json").unlink()
    save_checkpoint(out / "checkpoint.npz", {"k": 25}, record)
    changed = "0 1\n1 2\n2 3\n3 4\n4 0\n0 2\n" if role == "graph" else "1 0 0.3\n"
    (graph if role == "graph" else loss).write_text(changed)
    for again in (command, ("run", "--resume", out)):
        code, said, err = run_cli(*again)
        what = graph if role == "graph" else loss
        assert code == 2 and f"the {role} file {what} changed since the checkpoint" in err, err
    code, _, err = run_cli(*command, "--overwrite")
    assert code == 0, err


def test_resume_with_overwrite_is_refused_not_half_obeyed(tmp_path, run_cli):
    """--resume DIR --overwrite resumed and ignored --overwrite: the two cannot both hold."""
    out = tmp_path / "r"
    code, _, err = run_cli(
        "run",
        "paper-example-1",
        "-T",
        "40",
        "--checkpoint-every",
        "20",
        "--backend",
        "numpy",
        "--no-plots",
        "--no-progress",
        "--out",
        out,
    )
    assert code == 0, err
    code, _, err = run_cli("run", "--resume", out, "--overwrite")
    assert code == 2 and "--resume" in err and "--overwrite" in err and len(err.strip().splitlines()) == 1
