"""The command line: outputs of run and solve, and one-line errors with exit code 2 for bad input."""

import csv
import json
import subprocess
import sys

import numpy as np
import pytest
from numpy.testing import assert_allclose

from dgtd.cli import main
from dgtd.problems import exact
from dgtd.problems.generators import random_problem
from dgtd.problems.io import load_problem, save_problem


def cli(capsys, *args):
    """Run the CLI in-process; returns (exit code, stdout, stderr)."""
    try:
        main(list(args))
        code = 0
    except SystemExit as e:
        code = e.code
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture
def problem_file(tmp_path):
    p = random_problem(8, 3, 3, np.random.default_rng(99), gamma=0.7)
    path = tmp_path / "problem.npz"
    save_problem(str(path), p)
    return path, p


def write_npz(tmp_path, **arrays):
    base = dict(
        P=np.array([[0.5, 0.5], [0.2, 0.8]]),
        R=np.array([[1.0, 0.0], [0.0, 1.0]]),
        Phi=np.array([[1.0], [2.0]]),
        gamma=0.9,
    )
    path = tmp_path / "p.npz"
    np.savez(path, **{k: v for k, v in (base | arrays).items() if v is not None})
    return str(path)


def test_run_paper_example_writes_results(capsys, tmp_path):
    out = tmp_path / "out"
    code, stdout, _ = cli(
        capsys,
        "run",
        "paper-example-1",
        "-T",
        "2000",
        "--seeds",
        "2",
        "--out",
        str(out),
        "--no-progress",
        "--checkpoints",
        "10",
    )
    assert code == 0
    s = json.loads((out / "summary.json").read_text())
    assert_allclose(s["w_star"], [15.9032, 21.0284], atol=1e-4)
    assert np.array(s["w_last"]).shape == (2, 5, 2)
    assert np.array(s["w_avg"]).shape == (2, 5, 2)
    assert s["config"]["scenario"] == "paper-example-1" and s["config"]["kappa"] == 1.0
    assert s["config"]["alpha0"] == 10.0 and s["config"]["beta"] == 100.0 and s["config"]["iterations"] == 2000
    rows = list(csv.DictReader((out / "metrics.csv").open()))
    assert {r["metric"] for r in rows} >= {"error_last", "error_avg", "consensus", "mspbe_last"}
    assert max(int(r["step"]) for r in rows) == 2000
    assert (out / "iterates.png").stat().st_size > 1000 and (out / "errors.png").stat().st_size > 1000
    assert "w* = (15.9, 21.03)" in stdout
    assert stdout.count("%") >= 10  # one row per agent with relative errors


def test_solve_on_generated_file(capsys, problem_file):
    path, p = problem_file
    code, stdout, _ = cli(capsys, "solve", "--problem", str(path), "--graph", "complete", "--edge-prob", "0.5")
    assert code == 0
    out = json.loads(stdout)
    m = exact.Moments(load_problem(str(path)))
    assert_allclose(out["w_star"], exact.w_star(m), rtol=1e-12)
    assert max(out["kkt_residuals"].values()) < 1e-9
    assert np.allclose(out["v_star"], 0)


def test_run_on_generated_file_converges(capsys, problem_file, tmp_path):
    path, _ = problem_file
    out = tmp_path / "r"
    code, _, _ = cli(
        capsys,
        "run",
        "--problem",
        str(path),
        "--graph",
        "ring",
        "--edge-prob",
        "0.7",
        "-T",
        "100000",
        "--alpha0",
        "1",
        "--beta",
        "10",
        "--out",
        str(out),
        "--no-progress",
        "--no-plots",
    )
    assert code == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["max_error_avg"] < 0.05
    assert len(s["config"]["problem_sha256"]) == 64


BAD = {
    "rows do not sum to one": (dict(P=np.array([[0.5, 0.4], [0.2, 0.8]])), "sums to"),
    "negative entries": (dict(P=np.array([[1.5, -0.5], [0.2, 0.8]])), "negative"),
    "not ergodic": (dict(P=np.eye(2)), "not ergodic"),
    "Phi rank": (dict(Phi=np.array([[1.0, 2.0], [2.0, 4.0]])), "full column rank"),
    "shapes disagree": (dict(R=np.ones((2, 3))), "shape"),
    "gamma too large": (dict(gamma=1.5), "gamma"),
    "gamma not scalar": (dict(gamma=np.array([0.5, 0.5])), "scalar"),
    "NaN": (dict(Phi=np.array([[np.nan], [1.0]])), "NaN"),
    "missing array": (dict(Phi=None), "lacks Phi"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_problem_files(capsys, tmp_path, case):
    arrays, match = BAD[case]
    code, _, err = cli(capsys, "solve", "--problem", write_npz(tmp_path, **arrays))
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and match in err and "Traceback" not in err


def test_bad_files_and_networks(capsys, tmp_path):
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"not a zip file at all")
    pickled = tmp_path / "obj.npz"
    np.savez(pickled, P=np.array([object()], dtype=object), R=np.ones((1, 2)), Phi=np.ones((2, 1)), gamma=0.5)
    far = tmp_path / "far.txt"
    far.write_text("0 5\n")
    cut = tmp_path / "cut.txt"
    cut.write_text("0 1\n")  # agent 2 of 3 has no link
    good = write_npz(tmp_path)
    three = tmp_path / "three.npz"
    np.savez(three, P=np.array([[0.5, 0.5], [0.2, 0.8]]), R=np.ones((3, 2)), Phi=np.array([[1.0], [2.0]]), gamma=0.9)
    cases = [
        (("solve", "--problem", str(tmp_path / "missing.npz")), "is missing"),
        (("solve", "--problem", str(garbage)), "not an .npz file of plain arrays"),
        (("solve", "--problem", str(pickled)), "not an .npz file of plain arrays"),
        (("run", "--problem", good, "--graph", "ring", "--edge-prob", "0"), "disconnected"),
        (("run", "--problem", good, "--graph", str(far), "-T", "10"), "names agent 5"),
        (("run", "--problem", str(three), "--graph", str(cut), "-T", "10"), "disconnected"),
        (("run", "--problem", good, "--graph", "hypercube"), "neither a known graph nor an edge-list file"),
        (("run", "no-such-scenario"), "unknown scenario"),
        (("run", "paper-example-1", "--iterations", "0"), "iterations"),
        (("run", "paper-example-1", "--alpha0", "-1"), "alpha0"),
        (("run", "paper-example-1", "--backend", "gpu"), "backend"),
        (("run",), "name a scenario"),
    ]
    for args, match in cases:
        code, _, err = cli(capsys, *args)
        assert code == 2, (args, err)
        assert len(err.strip().splitlines()) == 1 and match in err and "Traceback" not in err, (args, err)


def test_real_process_exit_code_and_no_traceback(tmp_path):
    r = subprocess.run(
        [sys.executable, "-m", "dgtd.cli", "solve", "--problem", str(tmp_path / "nope.npz")],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "is missing" in r.stderr


def test_scenarios_lists_paper_example(capsys):
    code, out, _ = cli(capsys, "scenarios")
    assert code == 0 and "paper-example-1" in out


def test_scenarios_says_each_description_whole(capsys):
    """Each scenario's first paragraph, whole (it was cut at the docstring's first line, mid-sentence)."""
    from dgtd.scenarios import SCENARIOS

    _, out, _ = cli(capsys, "scenarios")
    listed = " ".join(out.split())
    for name, builder in SCENARIOS.items():
        first = " ".join(builder.__doc__.strip().split("\n\n")[0].split())
        assert f"{name} {first}" in listed, name
        assert first.endswith("."), name


def test_diverged_run_writes_standard_json(capsys, tmp_path):
    # Off-policy TD(0) on Baird diverges: the run reports it and summary.json stays standard JSON (null, not NaN).
    out = tmp_path / "td0"
    code, stdout, _ = cli(
        capsys, "run", "baird", "--algorithm", "td0", "-T", "100000", "--no-progress", "--no-plots", "--out", str(out)
    )
    assert code == 0 and "DIVERGED" in stdout
    s = json.loads((out / "summary.json").read_text(), parse_constant=lambda c: pytest.fail(f"non-standard {c}"))
    assert s["w_last"][0][0][0] is None


def test_a_notice_is_one_line_not_a_python_warning(capsys, monkeypatch, tmp_path):
    """The reference-backend notice reads as dgtd's own line, without Python's source line and category."""
    from dgtd.backends import compiled

    monkeypatch.setattr(compiled, "step_of", lambda algorithm: None)
    code, _, err = cli(
        capsys,
        "run",
        "paper-example-1",
        "--algorithm",
        "td0",
        "--alpha0",
        "0.1",
        "-T",
        "20",
        "--no-progress",
        "--no-plots",
        "--out",
        str(tmp_path / "o"),
    )
    assert code == 0, err
    notes = [line for line in err.splitlines() if "reference backend" in line]
    assert notes == [
        "dgtd: note: algorithm 'td0' writes update alone, not the one definition the compiled backend runs "
        "(dgtd.algorithms.base): it runs on the NumPy reference backend"
    ], err
    assert "UserWarning" not in err and "warnings.warn" not in err


def test_final_table_columns_line_up_however_long_the_vectors(capsys, tmp_path):
    """paper-example-2's weights print as long vectors: every row's error columns stay under their headers."""
    from types import SimpleNamespace

    from dgtd.cli import final_table

    w_star = np.array([0.0383, 0.06664, 0.1223, 0.2484, 0.547])
    w = np.broadcast_to(w_star * (1 + 1e-5 * np.arange(3)[:, None]), (1, 3, 5)).copy()
    result = SimpleNamespace(
        w_star=w_star, w_ref=w_star[None], w_last=w, w_avg=w, w_tail=w, info={}, report={}, rows=None
    )
    lines = final_table(result).splitlines()
    header = lines[1]
    for row in lines[2:5]:
        assert row.index("%") + 1 == header.index("err") + 3, (header, row)
        assert len(row) == len(header), (header, row)


def test_the_final_table_of_many_agents_shows_the_first_and_the_worst():
    """200 000 agents printed one line each took minutes and buried the run's words: beyond `TABLE_AGENTS` agents the
    table shows the first few and the worst few by their tail-averaged error, and says where every agent's rows are."""
    from types import SimpleNamespace

    from dgtd.cli import TABLE_AGENTS, final_table

    N, w_star = 5000, np.array([1.0, 2.0])
    w = np.broadcast_to(w_star, (1, N, 2)).copy()
    w[0, 4321] *= 1.5  # the worst agent
    w[0, 17] *= 1.2  # the second worst
    result = SimpleNamespace(
        w_star=w_star, w_ref=w_star[None], w_last=w, w_avg=w, w_tail=w, info={}, report={}, rows=None
    )
    lines = final_table(result).splitlines()
    assert len(lines) <= TABLE_AGENTS + 6
    agents = [int(line.split()[0]) for line in lines[2:] if line.split()[0].isdigit()]
    assert agents[:5] == [1, 2, 3, 4, 5] and {4322, 18} <= set(agents)
    assert any(f"{N - len(agents):,} agents more" in line for line in lines)


def test_compare_on_a_problem_file_says_which_steps_each_method_gets_and_why(capsys, tmp_path, problem_file):
    """The baselines' steps on a user's problem come from a rule: the line names each alpha0, the rule (garnet's
    tuned steps over the features' scale E|phi|^2) and --tune."""
    from dgtd.problems.exact import Moments
    from dgtd.scenarios.tuned import tuned_steps
    from dgtd.scenarios.user import feature_scale

    path, p = problem_file
    args = ["compare", "--problem", str(path), "-a", "dgtd,td0", "-T", "300", "--seeds", "1", "--no-plots"]
    code, out, err = cli(capsys, *args, "--no-progress", "--out", str(tmp_path / "c"))
    assert code == 0, err
    scale = feature_scale(Moments(p))
    td0 = tuned_steps("garnet")["td0"]["alpha0"] / scale
    assert f"td0 {td0:.3g}" in out and f"E|phi|^2 = {scale:.3g}" in out and "--tune" in out, out


def test_compare_names_its_winner_by_the_tail_average_with_the_spread_over_seeds():
    """dgtd compare never said which method was best, nor that its numbers are medians; by the last iterate TD(0)
    could look best while DGTD's tail average wins. The verdict ranks by value_error_tail, a diverged seed last."""
    from types import SimpleNamespace

    from dgtd.cli.compare import verdict

    def result(last, tail, diverged=(-1, -1, -1)):
        metrics = {"value_error_last": np.array([last]), "value_error_tail": np.array([tail])}
        return SimpleNamespace(metrics=metrics, info={"diverged_at": np.array(diverged)})

    results = {
        "td0": result([0.001, 0.001, 0.001], [0.0057, 0.006, 0.0055]),
        "dgtd": result([0.01, 0.01, 0.01], [0.0024, 0.0031, 0.0020]),
        "tdrc": result([0.0, 0.0, 0.0], [0.0001, np.nan, 0.0001], (-1, 40, -1)),
    }
    said = verdict(results)
    assert "median over 3 seed(s)" in said
    assert "lowest value tail: dgtd, 0.0024 (seeds 0.002 to 0.0031); then td0, 0.0057" in said
    assert "not ranked (a seed diverged or has no tail average): tdrc" in said


def test_many_agents_rows_go_to_agents_npz_and_read_back(run_cli, tmp_path, monkeypatch):
    """Beyond `INLINE_NUMBERS` per-agent numbers (a million agents' rows as JSON took minutes), summary.json names
    agents.npz, which holds them; `read_results` reads them back as the summary's arrays: equal to the numbers a
    summary.json of a small enough run holds itself."""
    import json

    import dgtd
    from dgtd.run import results

    common = ["run", "garnet", "--agents", 12, "-T", 200, "--no-progress", "--no-plots", "--backend", "numpy"]
    assert run_cli(*common, "--out", tmp_path / "inline")[0] == 0
    monkeypatch.setattr(results, "INLINE_NUMBERS", 100)
    assert run_cli(*common, "--out", tmp_path / "file")[0] == 0
    small = json.loads((tmp_path / "inline" / "summary.json").read_text())
    large = json.loads((tmp_path / "file" / "summary.json").read_text())
    assert "w_last" not in large and large["per_agent"]["file"] == "agents.npz"
    assert {k for k in small if k not in large} == set(large["per_agent"]["arrays"])
    read = dgtd.read_results(tmp_path / "file").summary
    for name in large["per_agent"]["arrays"]:
        np.testing.assert_array_equal(read[name], np.asarray(small[name]), err_msg=name)
    assert large["max_error_tail"] == small["max_error_tail"]


@pytest.mark.parametrize("n_agents", [7, 20, 21, 500])
def test_the_agents_the_table_shows_are_the_same_picked_by_parts(n_agents):
    """`_shown_agents` on each rank's agents, then on every rank's picks, picks what it picks over all the agents
    (the first ten, then the worst ten by their tail error, ties to the lower id), whatever the split."""
    from dgtd.cli import _shown_agents

    rng = np.random.default_rng(n_agents)
    ids = rng.permutation(n_agents)
    tail = rng.integers(0, 5, n_agents).astype(float)  # many ties
    tail[ids == 13] = np.nan if n_agents > 13 else tail[ids == 13]
    whole = _shown_agents(ids, tail, n_agents)
    of = dict(zip(ids.tolist(), tail))
    for parts in (2, 3, 8):
        picks = np.concatenate(
            [_shown_agents(p, np.array([of[i] for i in p]), n_agents) for p in np.array_split(ids, parts)]
        )
        assert np.array_equal(_shown_agents(picks, np.array([of[i] for i in picks]), n_agents), whole)
    if n_agents > 20:
        assert whole[:10].tolist() == list(range(10))


def test_agents_files_of_the_ranks_are_read_back_in_the_agents_order(tmp_path):
    """Each rank's agents' file holds its rows in its own order with their ids (``agent``); `read_agents` puts every
    file's rows together in the agents' order, on each array's agent axis."""
    from dgtd.run.results import npz_bytes, read_agents

    rng = np.random.default_rng(0)
    w = rng.standard_normal((2, 9, 3))  # (seeds, agents, features)
    theta = rng.standard_normal((9, 3))  # (agents, features)
    trace = rng.standard_normal((4, 2, 9))  # (checkpoints, seeds, agents)
    held = [np.array([4, 0, 7]), np.array([2, 8, 1, 5]), np.array([6, 3])]
    names = ["agents.npz", "agents.1.npz", "agents.2.npz"]
    for name, ids in zip(names, held):
        rows = {"w_last": w[:, ids], "theta_star": theta[ids], "agent_error_last": trace[:, :, ids], "agent": ids}
        (tmp_path / name).write_bytes(npz_bytes(rows))
    per_agent = {
        "file": "agents.npz",
        "parts": names,
        "arrays": ["agent_error_last", "theta_star", "w_last"],
        "axes": {"w_last": 1, "theta_star": 0, "agent_error_last": 2},
    }
    read = read_agents(tmp_path, per_agent, "run it again")
    assert np.array_equal(read["w_last"], w) and np.array_equal(read["theta_star"], theta)
    assert np.array_equal(read["agent_error_last"], trace)
