"""What a new user hits (the first items of the new-user review): options that did something else without a word,
tracebacks instead of one line, results lost to a Ctrl-C during the figures, files written 0600."""

from __future__ import annotations

import os
import stat

import numpy as np
import pytest
from helpers import one_line_error


def test_compare_with_zero_iterations_is_refused(run_cli, tmp_path):
    one_line_error(*run_cli("compare", "baird", "-T", "0", "--out", tmp_path / "c"), "iterations must be >= 1")
    assert not (tmp_path / "c").exists()


def test_resume_with_another_out_is_refused(run_cli, tmp_path):
    one_line_error(*run_cli("run", "--resume", tmp_path / "a", "--out", tmp_path / "b"), "--resume", "leave out --out")


def test_sweep_with_zero_workers_is_refused(run_cli, tmp_path):
    from pathlib import Path

    file = Path(__file__).resolve().parents[2] / "experiments" / "sweep-example-1.toml"
    one_line_error(*run_cli("sweep", file, "--workers", "0", "--out", tmp_path / "s"), "workers must be >= 1")
    assert not (tmp_path / "s").exists()


@pytest.mark.parametrize("graph, hint", [("rnig", "did you mean 'ring'?"), ("no-such-file.txt", "known graphs: path")])
def test_an_unknown_graph_name_lists_the_known_ones(run_cli, tmp_path, graph, hint):
    one_line_error(
        *run_cli("run", "paper-example-1", "--graph", graph, "-T", "10", "--out", tmp_path / "r"),
        "neither a known graph nor an edge-list file",
        hint,
    )


def test_bench_with_an_unknown_backend_is_one_line(run_cli, tmp_path):
    one_line_error(*run_cli("bench", "--backend", "foo", "--cases", "A", "--out", tmp_path), "unknown backend(s) foo")


def test_bench_with_an_unknown_algorithm_is_one_line(run_cli, tmp_path):
    one_line_error(
        *run_cli("bench", "--algorithm", "dgtd,td1", "--cases", "A", "--out", tmp_path),
        "unknown algorithm(s) td1",
        "or all",
    )


def test_a_huge_step_size_that_pins_the_iterates_to_the_boxes_is_reported(run_cli, tmp_path):
    code, out, err = run_cli(
        "run",
        "paper-example-1",
        "-T",
        "200",
        "--alpha0",
        "1e300",
        "--no-plots",
        "--no-progress",
        "--out",
        tmp_path / "r",
    )
    assert code == 0
    assert "warning:" in err and "100% of w" in err and "--alpha0" in err
    code, out, err = run_cli(
        "run", "paper-example-1", "-T", "100000", "--no-plots", "--no-progress", "--out", tmp_path / "ok"
    )
    assert code == 0 and "warning" not in err  # the paper's settings leave the boxes by then


def test_ctrl_c_while_drawing_keeps_the_numbers_and_says_so(run_cli, tmp_path, monkeypatch):
    import dgtd.plots

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(dgtd.plots, "plot_errors", interrupted)
    code, out, err = run_cli("run", "paper-example-1", "-T", "500", "--no-progress", "--out", tmp_path / "r")
    assert code == 130
    for name in ("summary.json", "metrics.csv", "trajectory.npz", "config.toml"):
        assert (tmp_path / "r" / name).exists(), name
    assert "results (summary.json, metrics.csv, trajectory.npz) are complete" in err and "dgtd plot" in err
    assert "Traceback" not in err


@pytest.mark.parametrize("umask, mode", [(0o022, 0o644), (0o002, 0o664), (0o077, 0o600)])
def test_results_files_take_the_users_umask(run_cli, tmp_path, umask, mode):
    old = os.umask(umask)
    try:
        code, _, _ = run_cli("run", "paper-example-1", "-T", "200", "--no-progress", "--out", tmp_path / "r")
    finally:
        os.umask(old)
    assert code == 0
    for name in ("summary.json", "metrics.csv", "trajectory.npz", "config.toml", "errors.png"):
        assert stat.S_IMODE((tmp_path / "r" / name).stat().st_mode) == mode, name


def test_a_damaged_checkpoint_is_one_line_without_pickle_advice(run_cli, tmp_path):
    out = tmp_path / "r"
    code, _, _ = run_cli("run", "paper-example-1", "-T", "100", "--no-progress", "--no-plots", "--out", out)
    assert code == 0
    import numpy as np

    np.savez(out / "checkpoint.npz", x=np.zeros(3))  # then cut off, then full of Python objects
    (out / "checkpoint.npz").write_bytes((out / "checkpoint.npz").read_bytes()[:100])
    one_line_error(*run_cli("run", "--resume", out), "not a complete .npz file", "start the run afresh")
    np.save(out / "checkpoint.npz", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    (out / "checkpoint.npz.npy").rename(out / "checkpoint.npz")
    code, o, err = run_cli("run", "--resume", out)
    one_line_error(code, o, err)
    assert "allow_pickle" not in err


def test_resuming_a_directory_without_a_run_says_so(run_cli, tmp_path):
    one_line_error(*run_cli("run", "--resume", tmp_path / "none"), "is not a directory")
    (tmp_path / "empty").mkdir()
    one_line_error(*run_cli("run", "--resume", tmp_path / "empty"), "holds no run (no config.toml)")


def _first_lines(path, n: int) -> str:
    """The first n lines of a file: a table cut off after a whole row."""
    return "".join(path.read_text().splitlines(keepends=True)[:n])


@pytest.mark.parametrize(
    "damage, words",
    [
        (lambda d: (d / "metrics.csv").write_text(_first_lines(d / "metrics.csv", 5)), "lacks the metric(s)"),
        (
            lambda d: (d / "metrics.csv").write_text("algorithm,seed,step,metric,value\ndgtd,0,x,error_avg,1\n"),
            "is not a number",
        ),
        (lambda d: (d / "metrics.csv").write_text("algorithm,seed\ndgtd,0\n"), "lacks the column(s)"),
        (lambda d: (d / "summary.json").write_text('{"w_star": '), "is not valid JSON"),
        (lambda d: (d / "trajectory.npz").write_bytes(b"PK\x03\x04junk"), "not a complete .npz file"),
        (lambda d: (d / "trajectory.npz").write_text("not arrays"), "is not an .npz file of plain arrays"),
    ],
)
def test_plot_on_damaged_results_is_one_line(run_cli, tmp_path, damage, words):
    out = tmp_path / "r"
    code, _, _ = run_cli("run", "paper-example-1", "-T", "300", "--no-progress", "--no-plots", "--out", out)
    assert code == 0
    damage(out)
    one_line_error(*run_cli("plot", out), words)


def test_a_single_agent_problem_runs(run_cli, tmp_path):
    import numpy as np

    np.savez(
        tmp_path / "one.npz", P=np.array([[0.5, 0.5], [0.5, 0.5]]), R=np.array([[1.0, 0.0]]), Phi=np.eye(2), gamma=0.9
    )
    code, out, err = run_cli(
        "run", "--problem", tmp_path / "one.npz", "-T", "300", "--no-progress", "--out", tmp_path / "r"
    )
    assert code == 0, err
    assert "1 agent, no links" in out and (tmp_path / "r" / "summary.json").exists()


def test_a_directory_never_mixes_two_runs(run_cli, tmp_path):
    """The same run again into its directory is fine; another configuration there is refused unless --overwrite,
    and the new run's directory holds its own files only (no figures of the previous run beside its numbers)."""
    out = tmp_path / "r"
    base = ("run", "paper-example-1", "-T", "300", "--no-progress", "--out", out)
    assert run_cli(*base)[0] == 0 and (out / "errors.png").exists()
    (out / "notes.txt").write_text("mine")
    assert run_cli(*base)[0] == 0  # the same configuration: redone
    one_line_error(*run_cli(*base, "--kappa", "0"), "holds the results of another run", "kappa", "--overwrite")
    code, _, err = run_cli(*base, "--kappa", "0", "--overwrite", "--no-plots")
    assert code == 0, err
    assert not (out / "errors.png").exists() and not (out / "iterates.png").exists()  # no stale figures
    assert (out / "summary.json").exists() and (out / "notes.txt").read_text() == "mine"  # the user's files stay


def test_the_kernels_load_before_the_first_iteration_and_the_times_are_reported(run_cli, tmp_path):
    """run() loads (or compiles) the kernel on an empty block and says so before the first block, so a progress
    bar started then measures the run alone; the empty block changes nothing; the command reports each phase."""
    import numpy as np

    from dgtd.algorithms import DGTD
    from dgtd.graphs import topologies
    from dgtd.graphs.random import random_edges
    from dgtd.problems.generators import random_problem
    from dgtd.run.loop import RunSettings, run
    from dgtd.sources.model import Sampling

    events = []
    p = random_problem(5, 4, 3, np.random.default_rng(0))
    net = random_edges(topologies.ring(4), 0.5)
    r = run(
        p,
        net,
        DGTD(alpha0=0.5, beta=10),
        Sampling(),
        RunSettings(iterations=50, seeds=2),
        progress=lambda n: events.append(("progress", n)),
        kernel_ready=lambda s: events.append(("ready", s)),
    )
    assert (
        events[0][0] == "ready" and events[0][1] >= 0 and [e for e, _ in events[1:]] == ["progress"] * (len(events) - 1)
    )
    plain = run(p, net, DGTD(alpha0=0.5, beta=10), Sampling(), RunSettings(iterations=50, seeds=2, block_size=7))
    assert np.array_equal(r.w_last, plain.w_last)
    code, out, err = run_cli("run", "paper-example-1", "-T", "300", "--out", tmp_path / "r")
    assert code == 0
    assert "s in all: setup" in out and "kernels" in out and "results and figures" in out
    assert "drawing the figures" in err


def test_plot_on_a_compare_directory_redraws_the_comparison(run_cli, tmp_path):
    out = tmp_path / "c"
    code, _, err = run_cli(
        "compare", "boyan", "-T", "2000", "--seeds", "2", "-a", "dgtd,gtd2", "--no-progress", "--no-plots", "--out", out
    )
    assert code == 0, err
    assert not (out / "compare.png").exists()
    code, text, err = run_cli("plot", out)
    assert code == 0, err
    assert (out / "compare.png").stat().st_size > 10_000 and (out / "consensus.png").exists()
    assert not (out / "errors.png").exists()  # not a single run's figure


def test_a_problem_too_large_to_solve_exactly_is_refused_before_anything_is_computed(monkeypatch):
    """A 20 000-state problem with identity features would take tens of GB and hours of dense linear algebra:
    refused in one line at once (the arrays below take no memory), naming the limit and how to raise it."""
    import time

    import numpy as np

    from dgtd.errors import DgtdInputError
    from dgtd.problems.model import make_problem

    S = 20_000
    t = time.perf_counter()
    with pytest.raises(DgtdInputError, match=r"about \d+\.\d GB .* DGTD_MEMORY_LIMIT_GB"):
        make_problem(np.broadcast_to(1.0 / S, (S, S)), np.ones((2, S)), np.broadcast_to(0.0, (S, S)), 0.9)
    assert time.perf_counter() - t < 1.0
    monkeypatch.setenv("DGTD_MEMORY_LIMIT_GB", "1e-6")
    with pytest.raises(DgtdInputError, match="over the limit of 1e-06 GB"):
        make_problem(np.full((4, 4), 0.25), np.ones((2, 4)), np.eye(4), 0.9)


def test_long_linear_algebra_keeps_ctrl_c_working():
    """The exact solution runs in a worker thread while the caller waits in short steps, so an interrupt is taken
    within a fraction of a second even while the worker is busy (here: sleeping) for seconds."""
    import signal
    import time

    from dgtd.run.loop import interruptible

    assert interruptible(lambda: 42) == 42
    with pytest.raises(ZeroDivisionError):
        interruptible(lambda: 1 / 0)

    def interrupt(*_):
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGALRM, interrupt)
    signal.setitimer(signal.ITIMER_REAL, 0.3)
    t = time.perf_counter()
    try:
        with pytest.raises(KeyboardInterrupt):
            interruptible(lambda: time.sleep(5))
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
    assert time.perf_counter() - t < 1.5


def test_an_interrupted_compare_keeps_the_finished_algorithms(run_cli, tmp_path, monkeypatch):
    import json

    import dgtd.run.compare as compare_module

    real_run, calls = compare_module.run, []

    def interrupted_second(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real_run(*args, **kwargs)

    monkeypatch.setattr(compare_module, "run", interrupted_second)
    out = tmp_path / "c"
    code, _, err = run_cli(
        "compare",
        "boyan",
        "-T",
        "1000",
        "--seeds",
        "2",
        "-a",
        "gtd2,td0,dgtd",
        "--no-progress",
        "--no-plots",
        "--out",
        out,
    )
    assert code == 130
    assert "the results of gtd2 are written" in err and "td0, dgtd did not run to the end" in err, err
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["algorithms"]) == {"gtd2"} and summary["config"]["missing"] == ["td0", "dgtd"]
    assert "gtd2" in (out / "metrics.csv").read_text()


def test_an_interrupted_compare_resumes_in_place(run_cli, tmp_path, monkeypatch):
    """The same command again runs only the algorithms that did not finish, and gives the numbers an uninterrupted
    comparison gives (every algorithm replays the same streams, so the finished ones need not run again)."""
    import json

    import dgtd.run.compare as compare_module

    args = ("compare", "boyan", "-T", "1000", "--seeds", "2", "-a", "gtd2,td0,dgtd", "--no-progress", "--no-plots")
    assert run_cli(*args, "--out", tmp_path / "whole")[0] == 0
    real_run, names, armed = compare_module.run, [], [True]

    def interrupted_second(problem, network, alg, *rest, **kwargs):
        names.append(alg.name)
        if len(names) == 2 and armed.pop():
            raise KeyboardInterrupt
        return real_run(problem, network, alg, *rest, **kwargs)

    monkeypatch.setattr(compare_module, "run", interrupted_second)
    out = tmp_path / "c"
    assert run_cli(*args, "--out", out)[0] == 130
    names.clear()
    armed.append(False)
    code, text, err = run_cli(*args, "--out", out)
    assert code == 0, err
    assert names == ["td0", "dgtd"] and "resuming" in text, (names, text)
    assert not (out / "parts").exists()
    whole, resumed = (json.loads((d / "summary.json").read_text()) for d in (tmp_path / "whole", out))
    assert "missing" not in resumed["config"]
    for name in ("gtd2", "td0", "dgtd"):
        assert resumed["algorithms"][name]["final"] == whole["algorithms"][name]["final"], name
    assert (out / "metrics.csv").read_text() == (tmp_path / "whole" / "metrics.csv").read_text()


def test_compare_into_a_directory_of_another_comparison_is_refused(run_cli, tmp_path):
    out = tmp_path / "c"
    args = ("compare", "boyan", "-T", "500", "--seeds", "1", "-a", "gtd2", "--no-progress", "--no-plots", "--out", out)
    assert run_cli(*args)[0] == 0
    one_line_error(*run_cli(*args[:3], "600", *args[4:]), "holds the results of another", "--overwrite")
    assert run_cli(*args[:3], "600", *args[4:], "--overwrite")[0] == 0


def test_a_run_that_ends_farther_from_w_star_than_it_started_says_so(run_cli, tmp_path):
    """`--bits 1` without error feedback: stochastic rounding onto {-s, s} adds noise as large as the messages, and
    garnet ended 1126 % off w* with no word. A run whose worst agent ends farther from w* than w = 0 is (100 %) is
    said not to have converged, with what to change for compressed links; a run that converges says nothing."""
    base = ("run", "garnet", "-T", "3000", "--seeds", "2", "--backend", "numpy", "--no-plots", "--no-progress")
    code, text, err = run_cli(*base, "--bits", "1", "--out", tmp_path / "a")
    assert code == 0, err
    assert "did not converge" in err and "--error-feedback" in err
    code, text, err = run_cli(*base, "--out", tmp_path / "b")
    assert code == 0 and "did not converge" not in err


def test_a_compare_row_is_repeated_by_the_dgtd_run_it_names(run_cli, tmp_path):
    """`dgtd run --help` said methods other than DGTD default to alpha0 0.1, a run on a problem file took 10 and
    `dgtd compare` 0.686: a run did not repeat its compare row. compare now prints, and keeps in summary.json, the
    options that repeat each row; `dgtd run` with them gives the row's tail error exactly (the same keyed samples)."""
    import json
    import re

    import numpy as np

    P = np.full((4, 4), 0.25)
    R = np.random.default_rng(0).uniform(0.0, 1.0, (3, 4))
    np.savez(tmp_path / "p.npz", P=P, R=R, Phi=np.eye(4)[:, :3] + 0.1, gamma=0.9)
    common = ("--problem", tmp_path / "p.npz", "-T", "1000", "--seeds", "2", "--backend", "numpy", "--no-plots")
    code, text, err = run_cli("compare", *common, "-a", "dgtd,tdc", "--no-progress", "--out", tmp_path / "c")
    assert code == 0, err
    said = re.search(r"tdc: (--algorithm tdc --alpha0 \S+ --beta \S+ --schedule \S+)", text)
    assert said and "repeat a row" in text, text
    row = json.loads((tmp_path / "c" / "summary.json").read_text())["algorithms"]["tdc"]
    assert row["run_options"] == said.group(1).split()
    code, _, err = run_cli("run", *common, *row["run_options"], "--no-progress", "--out", tmp_path / "r")
    assert code == 0, err
    tails = np.max(json.loads((tmp_path / "r" / "summary.json").read_text())["value_error_tail"], axis=1)
    assert np.median(tails) == row["final"]["value_error_tail"]["median"]


def test_run_help_says_where_the_steps_come_from():
    """The step options' help names the scenario's steps for any --algorithm, not each class's own default."""
    from click.testing import CliRunner

    from dgtd.cli import cli

    text = " ".join(CliRunner().invoke(cli, ["run", "--help"]).output.split())
    assert "the others 0.1" not in text and "whatever --algorithm" in text and "from the problem" in text


def test_ctrl_c_during_the_run_keeps_the_metrics_measured_so_far(run_cli, tmp_path, monkeypatch):
    """Ctrl-C in the middle of a run left only config.toml: metrics.csv now holds every checkpoint measured before it,
    each row the uninterrupted run's."""
    import dgtd.run.loop as loop

    command = ("run", "paper-example-1", "-T", 4000, "--checkpoints", 10, "--no-progress", "--no-plots")
    code, _, err = run_cli(*command, "--out", tmp_path / "whole")
    assert code == 0, err
    save = loop.save

    def interrupted_at_the_sixth(plan, rs, on_checkpoint):
        if rs.c == 6:
            raise KeyboardInterrupt
        save(plan, rs, on_checkpoint)

    monkeypatch.setattr(loop, "save", interrupted_at_the_sixth)
    code, _, err = run_cli(*command, "--out", tmp_path / "cut")
    assert code == 130, err
    whole, cut = ((tmp_path / d / "metrics.csv").read_text().splitlines() for d in ("whole", "cut"))
    steps = sorted({int(row.split(",")[2]) for row in whole[1:]})
    assert cut[0] == whole[0] and set(cut[1:]) <= set(whole[1:])
    assert sorted({int(row.split(",")[2]) for row in cut[1:]}) == steps[:6]
    assert not (tmp_path / "cut" / "summary.json").exists()


def test_a_tail_average_that_lags_the_last_iterate_is_said():
    """At 1 000 agents the tail average, the output to read, stood at 45.8 % where the last iterate was at 0.36 %,
    without a word: the note now says so where the tail lags by 3 times or more (and 1 % or more), and stays quiet
    where the tail average is the nearer (the usual case)."""
    from types import SimpleNamespace

    from dgtd.cli import tail_lags

    ref = np.ones((1, 4, 3))  # (seeds, agents, q)

    def run(last: float, tail: float):
        return SimpleNamespace(w_ref=ref, rows=None, w_last=ref * (1 + last), w_tail=ref * (1 + tail))

    said = tail_lags(run(0.0036, 0.458))
    assert "lags the last iterate" in said and "45.80%" in said and "0.36%" in said
    assert tail_lags(run(0.128, 0.0035)) == "" and tail_lags(run(0.001, 0.002)) == ""
