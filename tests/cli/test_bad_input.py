"""Every value is checked where it enters: one line and exit code 2, whatever class of bad input it is (numbers out
of range, a run too large for the machine, files that are not what their names say, recordings with impossible
columns, a user's simulator that raises or leaves an agent out).

Each class has several examples; a new bad input of a known class belongs in its table."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers import one_line_error

RUN = ("run", "paper-example-1", "--no-progress", "--no-plots")
HUGE = 10**23  # an integer no 64-bit field holds

NUMBERS = {
    "negative seed": (("--seed", -1, "-T", 10), "seed must be"),
    "seed beyond 64 bits": (("--seed", HUGE, "-T", 10), "seed must be"),
    "iterations beyond 64 bits": (("-T", HUGE), "iterations must be"),
    "seeds beyond 64 bits": (("--seeds", HUGE, "-T", 10), "seeds"),
    "block size beyond 64 bits": (("--block-size", HUGE, "-T", 10), "block_size must be"),
    "checkpoints beyond 64 bits": (("--checkpoints", HUGE, "-T", 10), "checkpoints must be"),
    "checkpoint-every beyond 64 bits": (("--checkpoint-every", HUGE, "-T", 10), "checkpoint_every must be"),
}


@pytest.mark.parametrize("case", sorted(NUMBERS))
def test_numbers_out_of_range(run_cli, tmp_path, case):
    args, words = NUMBERS[case]
    one_line_error(*run_cli(*RUN, *args, "--out", tmp_path / "o"), words)


@pytest.mark.parametrize("seeds", [10**8, 10**12])
def test_a_run_larger_than_the_machine_is_refused_with_its_estimate(run_cli, tmp_path, seeds):
    """Before anything is allocated: the estimate, the memory there is, and the option to lower."""
    code, out, err = run_cli(*RUN, "--seeds", seeds, "-T", 10, "--out", tmp_path / "o")
    one_line_error(code, out, err, "needs about", "GB", "--seeds")


def test_checkpoints_are_capped_at_the_iterations(run_cli, tmp_path):
    """--checkpoints beyond the iterations records every step once (it used to allocate for all of them)."""
    code, _, err = run_cli(*RUN, "-T", 50, "--checkpoints", 10**9, "--out", tmp_path / "o")
    assert code == 0, err
    steps = {int(line.split(",")[2]) for line in (tmp_path / "o" / "metrics.csv").read_text().splitlines()[1:]}
    assert steps == set(range(1, 51))


def _recordings(path: Path, **change) -> str:
    """Two recordings of two agents over ten steps on two states, with columns changed as ``change`` says."""
    n = 40
    columns = dict(
        seed=np.repeat([0, 1], n // 2),
        step=np.tile(np.repeat(np.arange(n // 4), 2), 2),
        agent=np.tile([0, 1], n // 2),
        state=np.tile([0, 1], n // 2),
        next_state=np.tile([1, 0], n // 2),
        reward=np.ones(n),
    )
    columns.update(change)
    np.savez(path, **columns)
    return str(path)


DATA = {
    "a column shorter than the others": (dict(state=np.zeros(39, int)), "columns of different lengths"),
    "a column longer than the others": (dict(reward=np.ones(41)), "columns of different lengths"),
    "a negative importance ratio": (dict(ratio=np.r_[np.ones(39), -1.0]), "ratio must be >= 0"),
    "a terminal flag of 2": (dict(terminal=np.r_[np.zeros(39, int), 2]), "terminal must be 0 or 1"),
    "a terminal flag of -1": (dict(terminal=np.r_[np.zeros(39, int), -1]), "terminal must be 0 or 1"),
}


@pytest.mark.parametrize("case", sorted(DATA))
def test_impossible_recordings(run_cli, tmp_path, case):
    change, words = DATA[case]
    data = _recordings(tmp_path / "data.npz", **change)
    one_line_error(*run_cli("run", "--data", data, "-T", 5, "--out", tmp_path / "o", "--no-progress"), words)


def test_files_whose_content_is_not_what_their_name_says(run_cli, tmp_path):
    """An .npy array saved under an .npz name, for every option that reads an .npz."""
    fake = tmp_path / "array.npz"
    with open(fake, "wb") as f:
        np.save(f, np.zeros(3))
    for args in (
        ("solve", "--problem", fake),
        ("run", "--problem", fake, "-T", 5),
        ("run", "--data", fake, "-T", 5),
        ("compare", "--problem", fake, "-T", 5),
    ):
        one_line_error(
            *run_cli(*args, "--out", tmp_path / "o") if args[0] != "solve" else run_cli(*args),
            "one .npy array, not an .npz",
        )


pytest.importorskip("pettingzoo", reason="the environment extra (pip install dgtd[envs]) is not installed")

ENVS = Path(__file__).resolve().parents[1] / "envs" / "chain.py"

ENV = {
    "step() raises": (("--env", f"{ENVS}:make_raising"), ("make_raising", "step()", "RuntimeError", "--debug")),
    "an agent left out of the rewards": (("--env", f"{ENVS}:make_missing_reward"), ("agent_2", "no reward")),
    "rewards that are not numbers": (("--env", f"{ENVS}:make_text_reward"), ("agent_0", "'high'", "number")),
    "a reward for an agent that does not exist": (("--env", f"{ENVS}:make_extra_reward"), ("agent_9",)),
    "no rewards dictionary": (("--env", f"{ENVS}:make_no_rewards"), ("rewards", "dict")),
    "agents other than its possible_agents": (  # a KeyError
        ("--env", f"{ENVS}:make_stranger_agents"),
        ("StrangerAgents", "no observation of agent_0", "stranger_0", "possible_agents"),
    ),
    "the policy raises": (
        ("--env", f"{ENVS}:make_chain", "--policy", f"{ENVS}:raising_policy"),
        ("raising_policy", "KeyError", "--debug"),
    ),
    "one-hot features of a state without a state space": (
        ("--env", f"{ENVS}:make_without_state_space", "--features", "one-hot"),
        ("declares no state_space", "Discrete(4)", "linear"),
    ),
    "the features raise": (
        ("--env", f"{ENVS}:make_chain", "--features", f"{ENVS}:raising_features"),
        ("raising_features", "ZeroDivisionError", "--debug"),
    ),
}


@pytest.mark.parametrize("case", sorted(ENV))
def test_a_users_env_that_goes_wrong(run_cli, tmp_path, case):
    args, words = ENV[case]
    one_line_error(*run_cli("run", *args, "-T", 50, "--out", tmp_path / "o", "--no-progress"), *words)


def test_debug_shows_the_users_traceback(run_cli, tmp_path):
    code, out, err = run_cli(
        "--debug", "run", "--env", f"{ENVS}:make_raising", "-T", 50, "--out", tmp_path / "o", "--no-progress"
    )
    assert code == 2
    assert "Traceback" in err and "the user's step() failed" in err and "chain.py" in err


def test_checkpoints_of_a_run_that_cannot_resume_are_refused_at_the_start(run_cli, tmp_path):
    code, out, err = run_cli(
        "run",
        "--env",
        f"{ENVS}:make_chain",
        "-T",
        50,
        "--checkpoint-every",
        10,
        "--out",
        tmp_path / "o",
        "--no-progress",
    )
    one_line_error(code, out, err, "cannot be resumed", "--checkpoint-every")
    assert not (tmp_path / "o" / "summary.json").exists()


def test_a_good_env_still_runs(run_cli, tmp_path):
    code, _, err = run_cli(
        "run", "--env", f"{ENVS}:make_chain", "-T", 50, "--out", tmp_path / "o", "--no-progress", "--no-plots"
    )
    assert code == 0, err
    assert json.loads((tmp_path / "o" / "summary.json").read_text())["config"]["iterations"] == 50


def test_an_env_file_imports_its_helper_modules(run_cli, tmp_path):
    """--env path/to/file.py:make puts the file's folder on the import path, as running the file would."""
    folder = tmp_path / "mine"
    folder.mkdir()
    (folder / "chain_helper.py").write_text(
        f"import sys\nsys.path.insert(0, {str(ENVS.parent.parent)!r})\nfrom envs.chain import make_chain\n"
    )
    (folder / "my_env.py").write_text("from chain_helper import make_chain\n\n\ndef make():\n    return make_chain()\n")
    code, _, err = run_cli(
        "run", "--env", f"{folder / 'my_env.py'}:make", "-T", 50, "--out", tmp_path / "o", "--no-progress", "--no-plots"
    )
    assert code == 0, err


def test_an_env_runs_step_size_reads_the_same_in_both_lines(run_cli, tmp_path):
    """The algorithm's line and the env's description print alpha0 alike (they read 9.99999 and 10)."""
    import re

    code, text, err = run_cli(
        "run",
        "--env",
        f"{ENVS}:make_chain",
        "--features",
        "one-hot",
        "-T",
        50,
        "--out",
        tmp_path / "o",
        "--no-progress",
        "--no-plots",
    )
    assert code == 0, err
    in_algorithm = re.search(r"alpha_k = ([0-9.e+-]+)/", text).group(1)
    in_description = re.search(r"lambda_max\(L\)\) = ([0-9.e+-]+)", text).group(1)
    assert in_algorithm == in_description, text


def test_a_full_disk_keeps_every_complete_file_and_the_final_table(run_cli, tmp_path, monkeypatch):
    """The disk fills while the results are written: the files that fit are complete, no partial file is left, the
    final table is printed anyway, and one line says which files could not be written."""
    import errno

    import dgtd.run.results as results

    real = results.atomic_write

    def full_disk(path, data):
        if Path(path).name in ("trajectory.npz", "summary.json"):
            raise OSError(errno.ENOSPC, "No space left on device")
        real(path, data)

    monkeypatch.setattr(results, "atomic_write", full_disk)
    out = tmp_path / "o"
    code, text, err = run_cli(*RUN, "-T", 200, "--out", out)
    assert code == 2
    assert "w* = (15.9, 21.03)" in text  # the final table, from the numbers in memory
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "trajectory.npz" in lines[0] and "summary.json" in lines[0], err
    assert "No space left" in lines[0] and "metrics.csv" in lines[0]
    assert sorted(p.name for p in out.iterdir() if not p.name.startswith(".dgtd")) == [
        "bands.csv",
        "config.toml",
        "metrics.csv",
    ]
    assert len((out / "metrics.csv").read_text().splitlines()) > 1


def test_whole_numbers_given_as_floats_are_counts_and_fractions_are_refused():
    """In Python or TOML, 1e4 iterations is a count (it was accepted before the bounds, and stays so); 2.5 is not."""
    from dgtd.errors import DgtdInputError
    from dgtd.run.loop import RunSettings

    settings = RunSettings(iterations=1e4, seeds=2.0)
    assert settings.iterations == 10_000 and isinstance(settings.iterations, int) and settings.seeds == 2
    for bad in (dict(iterations=2.5), dict(seeds=float("nan")), dict(seed=1e30), dict(block_size=True)):
        with pytest.raises(DgtdInputError, match="whole number"):
            RunSettings(**bad)


CONVENTIONS = {
    "skipped restarts of a continuing task": (("run", "paper-example-1", "--restarts", "skipped"), "episodic"),
    "skipped restarts in solve": (("solve", "garnet", "--restarts", "skipped"), "episodic"),
    "restarts of a simulator's samples": (("run", "paper-example-2", "--restarts", "skipped"), "--restarts"),
    "an unknown convention": (("run", "boyan", "--restarts", "never"), "never"),
}


@pytest.mark.parametrize("case", sorted(CONVENTIONS))
def test_an_episodic_convention_that_cannot_apply(run_cli, tmp_path, case):
    args, words = CONVENTIONS[case]
    one_line_error(*run_cli(*args, *(("--out", tmp_path / "o", "-T", 10) if args[0] == "run" else ())), words)


def test_skipped_restarts_are_recorded_and_change_the_answer(run_cli, tmp_path):
    """`dgtd solve` and `dgtd run` both say which convention they used; the exact w* moves with it."""
    solved = {}
    for conv in ("sampled", "skipped"):
        code, out, _ = run_cli("solve", "boyan", "--restarts", conv)
        assert code == 0
        solved[conv] = json.loads(out)
        assert solved[conv]["restarts"] == conv
    assert solved["skipped"]["stationary_distribution"][-1] == 0.0 < solved["sampled"]["stationary_distribution"][-1]
    assert abs(solved["skipped"]["w_star"][3] - solved["sampled"]["w_star"][3]) > 0.05
    code, _, _ = run_cli("run", "boyan", "--restarts", "skipped", "-T", 100, "--no-plots", "--out", tmp_path / "r")
    summary = json.loads((tmp_path / "r" / "summary.json").read_text())
    assert code == 0 and summary["config"]["restarts"] == "skipped"
    np.testing.assert_allclose(summary["w_star"], solved["skipped"]["w_star"], rtol=1e-12)


LINKS = {
    "a loss of 1": (("--loss", "1"), "in [0, 1)"),
    "a negative loss": (("--loss", "-0.2"), "in [0, 1)"),
    "a loss list of the wrong length": (("--loss", "0.1,0.2"), "one per agent (5 here"),
    "a loss that is neither": (("--loss", "lossy"), "neither a probability"),
    "a burst shorter than one step": (("--loss", "0.2", "--burst", "0.5"), "at least 1"),
    "a burst too short for the loss": (("--loss", "0.9", "--burst", "2"), "loss / (1 - loss)"),
    "a burst without a loss": (("--burst", "5"), "give the loss too"),
    "a burst that is not a number": (("--loss", "0.2", "--burst", "long"), "burst"),
    "reweighting without a loss": (("--reweight",), "give the loss too"),
    "a negative delay": (("--delay", "-1"), "delay: the most steps"),
    "zero bits": (("--bits", "0"), "bits: the bits a number"),
    "a wake probability of 0": (("--wake", "0"), "wake: the probability"),
    "a wake list of the wrong length": (("--wake", "0.5,0.5"), "one per agent (5 here"),
    "top-k of 0": (("--top-k", "0"), "top_k"),
    "error feedback without compression": (("--error-feedback",), "give --bits B"),
    "error feedback with delay": (("--bits", "4", "--error-feedback", "--delay", "2"), "not supported"),
    "asynchronous ranks in one process": (("--asynchronous",), "for agents spread over the ranks of an mpiexec"),
    "a staleness without asynchronous ranks": (("--staleness", "2"), "give --asynchronous"),
    "a negative staleness": (("--asynchronous", "--staleness", "-1"), "staleness must be >= 0"),
}


@pytest.mark.parametrize("case", sorted(LINKS))
def test_bad_link_parameters(run_cli, tmp_path, case):
    args, words = LINKS[case]
    one_line_error(*run_cli(*RUN, "-T", 10, *args, "--out", tmp_path / "o"), words)


def test_a_link_file_naming_a_pair_that_is_not_an_edge(run_cli, tmp_path):
    links = tmp_path / "links.txt"
    links.write_text("0 1 0.5\n0 2 0.5\n")  # paper-example-1's ring links 0-1, not 0-2
    one_line_error(*run_cli(*RUN, "-T", 10, "--loss", links, "--out", tmp_path / "o"), "line 2", "not linked")


def test_a_lossy_run_records_its_links_and_converges_elsewhere(run_cli, tmp_path):
    """--loss by receiver: config.toml and summary.json record it; the run's reference is the moved fixed point
    (47 % from w* in value error, `dgtd solve` gives the same) and fewer messages arrive than on perfect links."""
    args = ("-T", 2000, "--alpha0", 0.5, "--beta", 1000)
    code, _, err = run_cli(*RUN, *args, "--loss", "0.1,0.5,0,0.8,0.3", "--out", tmp_path / "lossy")
    assert code == 0, err
    code, _, err = run_cli(*RUN, *args, "--out", tmp_path / "perfect")
    assert code == 0, err
    lossy, perfect = (json.loads((tmp_path / d / "summary.json").read_text()) for d in ("lossy", "perfect"))
    assert lossy["config"]["loss"] == [0.1, 0.5, 0.0, 0.8, 0.3]
    assert "loss = [" in (tmp_path / "lossy" / "config.toml").read_text()
    assert lossy["w_fixed_value_distance"] > 0.4 and perfect["w_fixed_value_distance"] == 0.0
    assert lossy["messages"][0] < 0.75 * perfect["messages"][0]
    code, out, _ = run_cli("solve", "paper-example-1", "--loss", "0.1,0.5,0,0.8,0.3")
    solved = json.loads(out)
    np.testing.assert_allclose(solved["w_fixed"], lossy["w_fixed"], rtol=1e-12)
    assert abs(sum(solved["agent_weights"]) - 1) < 1e-12 and max(solved["agent_weights"]) > 0.4


LAUNCHES = {
    "hosts without ranks": (("--hosts", "hosts.txt"), "give --ranks too"),
    "no ranks": (("--ranks", "0"), "at least 1"),
    "a host file that is not there": (("--ranks", "2", "--hosts", "nowhere.txt"), "no such file"),
    "a host file line that is not host:slots": (("--ranks", "2", "--hosts", "hosts.txt"), "line 2"),
}


@pytest.mark.parametrize("case", sorted(LAUNCHES))
def test_bad_launches_are_one_line_before_any_rank_starts(run_cli, tmp_path, monkeypatch, case):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "hosts.txt").write_text("# the machines\nnode1:two\n")
    args, words = LAUNCHES[case]
    one_line_error(*run_cli(*RUN, "-T", 10, *args, "--out", tmp_path / "o"), words)
    assert not (tmp_path / "o").exists()


def test_ranks_without_the_mpi_extra_say_how_to_install_it(run_cli, tmp_path, monkeypatch):
    from dgtd.cli import launch

    monkeypatch.setattr(launch.shutil, "which", lambda *a, **k: None)  # no mpiexec anywhere
    one_line_error(*run_cli(*RUN, "-T", 10, "--ranks", 2, "--out", tmp_path / "o"), "pip install 'dgtd[mpi]'")
    assert not (tmp_path / "o").exists()


def test_a_byte_order_mark_is_no_part_of_a_toml_file_or_an_edge_list(tmp_path, run_cli):
    """An editor's UTF-8 BOM gave "Invalid statement (line 1, column 1)" and "nodes \\ufeff0,1"."""
    bom = b"\xef\xbb\xbf"
    edges = tmp_path / "edges.txt"
    edges.write_bytes(bom + b"0 1\n1 2\n2 3\n3 4\n4 0\n")
    toml = tmp_path / "exp.toml"
    toml.write_bytes(bom + f'[problem]\nscenario = "paper-example-1"\n\n[network]\ngraph = "{edges}"\n'.encode())
    out = tmp_path / "out"
    code, _, err = run_cli("run", toml, "-T", "30", "--backend", "numpy", "--no-plots", "--no-progress", "--out", out)
    assert code == 0, err
    assert (out / "summary.json").exists()


def _problem_file(path, **arrays):
    P = np.array([[0.5, 0.5], [0.5, 0.5]])
    base = dict(P=P, R=np.ones((2, 2)), Phi=np.eye(2), gamma=0.9)
    np.savez(path, **{**base, **arrays})
    return path


@pytest.mark.parametrize(
    "arrays, said",
    [
        (dict(P=np.zeros((0, 0)), R=np.zeros((1, 0)), Phi=np.zeros((0, 1))), "no states"),
        (dict(Phi=np.zeros((2, 0))), "no features"),
        (dict(Phi=np.eye(2) * 1e-200), "too small"),
        (dict(Phi=np.eye(2) * 1e200), "too large"),
        (dict(R=np.ones((2, 2)) * 1e300), "too large"),
    ],
    ids=["zero states", "no feature columns", "features x 1e-200", "features x 1e200", "rewards x 1e300"],
)
def test_a_problem_out_of_range_is_one_line_not_a_traceback_or_nan(tmp_path, run_cli, arrays, said):
    """A zero-size problem, Phi with no columns or times 1e-200 gave tracebacks (a reshape, a division by zero in the
    sample cap); features times 1e200 and rewards times 1e300 ran to "nan%" errors with NumPy's warnings."""
    path = _problem_file(tmp_path / "p.npz", **arrays)
    code, _, err = run_cli(
        "run", "--problem", path, "-T", 50, "--backend", "numpy", "--no-plots", "--no-progress", "--out", tmp_path / "o"
    )
    assert code == 2 and said in err and len(err.strip().splitlines()) == 1, err


def test_a_pipe_or_a_symlink_loop_is_named_for_what_it_is(tmp_path, run_cli):
    """--problem a named pipe with no writer blocked for ever; a symlink loop was called missing, and --out through
    one gave a RuntimeError traceback."""
    import os

    pipe = tmp_path / "pipe.npz"
    os.mkfifo(pipe)
    code, _, err = run_cli("run", "--problem", pipe, "-T", 10, "--no-plots", "--no-progress")
    assert code == 2 and "not a regular file" in err
    os.symlink(tmp_path / "b", tmp_path / "a")
    os.symlink(tmp_path / "a", tmp_path / "b")
    code, _, err = run_cli("run", "--problem", tmp_path / "a", "-T", 10, "--no-plots", "--no-progress")
    assert code == 2 and "symbolic link" in err and "missing" not in err
    code, _, err = run_cli(
        "run",
        "paper-example-1",
        "-T",
        10,
        "--backend",
        "numpy",
        "--no-plots",
        "--no-progress",
        "--out",
        tmp_path / "a" / "x",
    )
    assert code == 2 and "symbolic link" in err and len(err.strip().splitlines()) == 1, err


@pytest.mark.parametrize(
    "arrays, said, not_said",
    [
        (dict(sigma=np.inf), "sigma must be a finite number", "at least the largest"),
        (dict(terminal=np.array([0.0, np.nan])), "terminal holds nan", "shape"),
    ],
    ids=["sigma inf", "nan in terminal"],
)
def test_a_problem_files_fault_is_named_for_what_it_is(tmp_path, run_cli, arrays, said, not_said):
    """sigma = inf was refused by a rule inf meets ("at least the largest mean reward"); a NaN in terminal was
    reported as a wrong shape (the shape was right)."""
    path = _problem_file(tmp_path / "p.npz", **arrays)
    code, _, err = run_cli("run", "--problem", path, "-T", 50, "--no-plots", "--no-progress", "--out", tmp_path / "o")
    assert code == 2 and said in err and not_said not in err and len(err.strip().splitlines()) == 1, err


def test_a_recording_with_no_rows_says_so_not_that_it_lacks_its_columns(tmp_path, run_cli):
    """A header-only CSV and an empty Parquet file have every column; they were said to lack them."""
    header = "seed,step,agent,phi_0,next_phi_0,reward\n"
    (tmp_path / "head.csv").write_text(header)
    files = [tmp_path / "head.csv"]
    pa = pytest.importorskip("pyarrow")
    import pyarrow.parquet as pq

    columns = header.strip().split(",")
    types = [pa.int64()] * 3 + [pa.float64()] * 3
    pq.write_table(pa.table({c: pa.array([], t) for c, t in zip(columns, types)}), tmp_path / "empty.parquet")
    files.append(tmp_path / "empty.parquet")
    for path in files:
        code, _, err = run_cli("run", "--data", path, "-T", 10, "--no-plots", "--no-progress", "--out", tmp_path / "o")
        assert code == 2 and "holds no rows" in err and "lacks" not in err, err


def test_agents_with_a_problem_file_speaks_of_the_files_agents(tmp_path, run_cli):
    """`--problem F --agents 5` said "params are a scenario's parameters": the user gave --agents, not params."""
    path = _problem_file(tmp_path / "p.npz")
    code, _, err = run_cli("run", "--problem", path, "--agents", 5, "-T", 10, "--no-progress", "--out", tmp_path / "o")
    assert code == 2 and "--agents" in err and "the rows of its R (2 agents)" in err and "params" not in err, err


def test_a_changed_edge_list_is_blamed_not_the_step_derived_from_it(tmp_path, run_cli, monkeypatch):
    """A run on a problem file over an edge list, cut off after a checkpoint; the edge list changes, the same
    command again: the step derived from the problem and its network changed with it, and the refusal blamed that
    ("beta = 5170 there, 8650 here") instead of the file."""
    S = 10
    P = np.zeros((S, S))
    for s in range(S):
        P[s, max(s - 1, 0)] += 0.5
        P[s, min(s + 1, S - 1)] += 0.5
    x = np.linspace(0.0, 1.0, S)
    Phi = np.stack([np.ones(S), x, np.cos(np.pi * x)], 1)
    R = np.random.default_rng(1).uniform(0.0, 1.0, (6, S))
    np.savez(tmp_path / "chain.npz", P=P, R=R, Phi=Phi, gamma=0.9)
    edges = tmp_path / "edges.txt"
    edges.write_text("0 1\n1 2\n2 3\n3 4\n4 5\n5 0\n")
    out = tmp_path / "o"
    command = ("run", "--problem", tmp_path / "chain.npz", "--graph", edges, "-T", 400, "--checkpoint-every", 100)
    command += ("--backend", "numpy", "--no-plots", "--no-progress", "--out", out)
    with monkeypatch.context() as m:  # as if cut off after its last checkpoint
        m.setattr("dgtd.cli.job.remove_checkpoint", lambda path: None)
        code, _, err = run_cli(*command)
    assert code == 0 and (out / "checkpoint.npz").exists(), err
    (out / "summary.json").unlink()
    edges.write_text("0 1\n1 2\n2 3\n3 4\n4 5\n5 0\n0 3\n1 4\n2 5\n")
    code, _, err = run_cli(*command)
    assert code == 2 and "the graph file" in err and "changed since the checkpoint" in err and "beta" not in err, err


def _learning_file(path: Path, **change) -> Path:
    """pull-away's team MDP as a learning problem file, every agent starting at (0.9, 0.1), change applied."""
    from dgtd.problems import team

    mdp = team.pull_away()
    arrays = dict(P=mdp.P, R=mdp.R, Phi=mdp.Phi, gamma=mdp.gamma, **{f"policy_{i}": [[0.9, 0.1]] * 3 for i in range(4)})
    np.savez(path, **{**arrays, **change})
    return path


NEW_USERS_INPUTS = {  # each ended in a traceback, or ran and said nothing of what was wrong
    "a NaN in a starting policy": (
        lambda d: ("learn", "--problem", _learning_file(d / "p.npz", policy_0=[[np.nan, 0.1], [0.9, 0.1], [0.9, 0.1]])),
        ("policy 0", "NaN"),
    ),
    "a 1-D starting policy": (  # (blamed on the action counts)
        lambda d: ("learn", "--problem", _learning_file(d / "p.npz", policy_0=[0.9, 0.1])),
        ("policy_0", "shape (2,)", "(S, A_0)", "3 states"),
    ),
    "a 3-D starting policy": (
        lambda d: ("learn", "--problem", _learning_file(d / "p.npz", policy_0=np.full((3, 2, 1), 0.5))),
        ("policy_0", "shape (3, 2, 1)"),
    ),
    "a NaN reward of a learning file": (  # (said "must be finite with shape (4, 3, 16), got (4, 3, 16)")
        lambda d: (
            "learn",
            "--problem",
            _learning_file(d / "p.npz", R=np.pad([[[np.nan]]], ((0, 3), (0, 2), (0, 15)))),
        ),
        ("R holds NaN", "agent 0, state 0, joint action 0"),
    ),
    "R over s' of the wrong length": (
        lambda d: ("learn", "--problem", _learning_file(d / "p.npz", R=np.zeros((4, 3, 16, 2)))),
        ("R", "(4, 3, 16, 2)", "(N, S, A, S)"),
    ),
    "a negative graph seed": (
        lambda d: ("run", "paper-example-1", "--graph", "small-world", "--graph-seed", -1),
        ("graph_seed must be >= 0",),
    ),
    "no agents": (lambda d: ("run", "garnet", "--agents", 0), ("n_agents must be >= 1",)),
    "a round longer than the run": (  # (it learned nothing, exit 0)
        lambda d: ("learn", "pull-away", "--batch", 1000),
        ("--batch 1000", "-T 10", "first round"),
    ),
    "a graph's name in capitals": (  # (its list of known graphs left the chunked ones out)
        lambda d: ("run", "paper-example-1", "--graph", "Small-World"),
        ("small-world, sparse-random, geometric", "did you mean 'small-world'"),
    ),
    "fewer than no agents": (lambda d: ("run", "garnet", "--agents", -5), ("n_agents must be >= 1",)),
}


@pytest.mark.parametrize("case", sorted(NEW_USERS_INPUTS))
def test_what_new_users_typed_is_one_line(run_cli, tmp_path, case):
    args, words = NEW_USERS_INPUTS[case]
    one_line_error(*run_cli(*args(tmp_path), "-T", 10, "--no-progress", "--no-plots", "--out", tmp_path / "o"), *words)


def test_a_policy_row_that_does_not_sum_to_1_is_called_a_distribution_not_a_transition_matrix(run_cli, tmp_path):
    path = _learning_file(tmp_path / "p.npz", policy_1=[[0.5, 0.1], [0.9, 0.1], [0.9, 0.1]])
    code, out, err = run_cli("learn", "--problem", path, "-T", 10, "--no-progress", "--out", tmp_path / "o")
    one_line_error(code, out, err, "row 0 of policy 1 sums to 0.6", "distribution")
    assert "transition matrix" not in err
