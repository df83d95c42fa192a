"""Behaviour of the methods side by side, the metrics over time, divergence, and `dgtd compare`."""

from __future__ import annotations

import csv
import json
import subprocess
import sys

import numpy as np
import pytest

from dgtd.algorithms import make_algorithm
from dgtd.cli import main
from dgtd.graphs import topologies
from dgtd.graphs.random import random_edges
from dgtd.problems import exact, tasks
from dgtd.run.compare import CompareSettings, compare, configs_for
from dgtd.run.loop import RunSettings, run
from dgtd.scenarios import get_scenario
from dgtd.sources.model import Sampling


def test_on_baird_td0_diverges_and_dgtd_and_gtd2_do_not():
    """Same samples, same step sizes alpha_k = 0.1 / sqrt(k + 100): off-policy TD(0) is reported as diverged on
    every seed (its expected update has an eigenvalue of A with negative real part, -0.24); GTD2 and DGTD stay
    finite and end at less than half the relative error they started with (0.65 at w0)."""
    sc = get_scenario("baird")
    st = RunSettings(iterations=100_000, seeds=3, checkpoints=20, backend="numba")
    cs = CompareSettings(("td0", "gtd2", "dgtd"), st)
    res, _, _ = compare(sc.problem, sc.network, sc.sampling, configs_for(sc, cs.algorithms), cs)
    assert np.min(np.linalg.eigvals(exact.Moments(sc.problem).A).real) < -0.2
    assert np.all(res["td0"].info["diverged_at"] > 0)
    assert np.all(np.isnan(res["td0"].metrics["error_last"][-1]))
    assert np.all(res["td0"].info["counts"]["diverged"][-1] == 1)
    start = exact.relative_error(sc.problem.w0, res["gtd2"].w_star)
    for name in ("gtd2", "dgtd"):
        r = res[name]
        assert np.all(r.info["diverged_at"] < 0) and np.all(r.info["counts"]["diverged"] == 0)
        assert np.all(np.isfinite(r.w_last))
        assert r.metrics["error_last"][-1].max() < 0.5 * start


def consensus_problem():
    """5 agents with different rewards on an 8-state on-policy Garnet chain, 3 features."""
    return tasks.garnet(n_states=8, branching=3, n_agents=5, n_features=3, gamma=0.8, seed=2)


def test_consensus_td0_and_dgtd_reach_consensus_and_local_does_not_reach_w_star():
    """On a connected ring (links up with p = 0.7), on-policy: the agents of consensus TD(0) and DGTD end
    within 1e-5 of each other (consensus error relative to N |w*|^2; measured at most 4.4e-7 over base seeds
    0..2) and near w* (averaged iterate within 3 %; measured at most 0.8 %). `local`'s agents go to their own
    fixed points A^-1 b_i (within 5 %; measured 0.6 %), the worst of which is 23.7 % from w*, and stay apart.
    """
    p = consensus_problem()
    net = random_edges(topologies.ring(5), 0.7)
    m = exact.Moments(p)
    w_star = exact.w_star(m)
    scale = p.n_agents * float(w_star @ w_star)
    st = RunSettings(iterations=100_000, seeds=2, checkpoints=10, backend="numba")
    own = np.linalg.solve(m.A, m.b.T).T
    assert exact.relative_error(own, w_star).max() > 0.2
    for name, alpha0 in (("consensus-td0", 1.0), ("dgtd", 1.0)):
        r = run(p, net, make_algorithm(name, alpha0=alpha0, beta=10.0), Sampling(), st)
        assert r.metrics["consensus"][-1].max() / scale < 1e-5
        assert r.metrics["error_avg"][-1].max() < 0.03
    r = run(p, net, make_algorithm("local", alpha0=1.0, beta=10.0), Sampling(), st)
    assert r.metrics["error_last"][-1].min() > 0.2
    assert np.abs(r.w_tail - own).max() / np.abs(own).max() < 0.05
    assert r.metrics["consensus"][-1].min() / scale > 1e-2


def test_samples_and_messages_are_counted():
    """Samples: N per step. Messages: the algorithm's messages x 2 directions x links up, per step; on a fixed ring of
    4 that is exactly T * 4 * 2 * (2 for DGTD: w and v + mu, 1 for consensus TD(0), 2 for pd-td, 0 for the others),
    and 64 bits per number; on a random network it is the same multiple of the number of links up, whose mean is
    p E T."""
    p = consensus_problem()
    p4 = tasks.garnet(n_states=8, branching=3, n_agents=4, n_features=3, gamma=0.8, seed=2)
    T = 3000
    st = RunSettings(iterations=T, seeds=2, checkpoints=4, backend="numpy")
    fixed = random_edges(topologies.ring(4), 1.0)
    for name, k in (("dgtd", 2), ("consensus-td0", 1), ("pd-td", 2), ("gtd2", 0), ("local", 0)):
        r = run(p4, fixed, make_algorithm(name), Sampling(), st)
        assert np.all(r.info["counts"]["messages"][-1] == T * 4 * 2 * k)
        assert np.all(r.info["counts"]["bits"][-1] == T * 4 * 2 * k * 3 * 64)
        assert np.all(r.info["counts"]["samples"][:, 0] == 4 * r.steps)
    r = run(p, random_edges(topologies.ring(5), 0.5), make_algorithm("dgtd"), Sampling(), st)
    links = r.info["counts"]["messages"][-1] / 4
    assert np.all(links == np.round(links))
    assert np.all(np.abs(links - 0.5 * 5 * T) < 5 * np.sqrt(0.25 * 5 * T))  # 5 standard deviations
    assert np.all(np.diff(r.info["counts"]["messages"], axis=0) >= 0)


def test_compare_uses_the_same_samples_for_every_algorithm():
    """Seed k of every algorithm sees the same stream: consensus TD(0) on a graph whose links are never up
    is `local`-like TD(0) per agent, and with one agent it is centralised TD(0), number for number."""
    p = tasks.garnet(n_states=8, branching=3, n_agents=1, n_features=3, gamma=0.8, seed=2)
    net = random_edges(topologies.path(1), 1.0)
    st = RunSettings(iterations=2000, seeds=3, checkpoints=3, backend="numpy")
    cs = CompareSettings(("td0", "consensus-td0"), st)
    cfg = {n: make_algorithm(n, alpha0=0.5, beta=10.0) for n in cs.algorithms}
    res, _, _ = compare(p, net, Sampling(), cfg, cs)
    np.testing.assert_allclose(res["td0"].w_last, res["consensus-td0"].w_last, rtol=1e-13)


def test_tuning_picks_a_step_size_that_does_not_diverge(tmp_path):
    sc = get_scenario("baird")
    st = RunSettings(iterations=5000, seeds=1, checkpoints=5, backend="numba")
    cs = CompareSettings(("td0",), st, tune=True, tune_seeds=1, tune_grid=(0.1, 10.0, 100.0))
    res, used, tables = compare(
        sc.problem, sc.network, sc.sampling, {"td0": make_algorithm("td0", alpha0=0.1, beta=100.0)}, cs
    )
    assert used["td0"].alpha0 == pytest.approx(0.01)
    assert [s for _, s in tables["td0"]][1:] == [float("inf"), float("inf")]


def test_cli_compare_writes_csv_summary_and_plots(tmp_path, capsys):
    out = tmp_path / "cmp"
    main(
        [
            "compare",
            "baird",
            "--algorithms",
            "dgtd,td0,consensus-td0",
            "--seeds",
            "2",
            "-T",
            "4000",
            "--checkpoints",
            "8",
            "--out",
            str(out),
            "--no-progress",
        ]
    )
    text = capsys.readouterr().out
    assert "td0" in text and "diverged" in text
    rows = list(csv.DictReader(open(out / "metrics.csv")))
    assert set(rows[0]) == {"algorithm", "seed", "step", "metric", "value"}
    assert {r["algorithm"] for r in rows} == {"dgtd", "td0", "consensus-td0"}
    assert {"error_last", "error_avg", "mspbe_last", "consensus", "samples", "messages", "diverged"} <= {
        r["metric"] for r in rows
    }
    summary = json.loads((out / "summary.json").read_text())
    assert summary["algorithms"]["td0"]["config"]["alpha0"] == 0.02  # the scenario's comparison step (COMPARE_STEPS)
    assert summary["problem"] == "baird" and len(summary["w_star"]) == 8
    for name in ("compare.png", "consensus.png"):
        assert (out / name).stat().st_size > 10_000
    agents = np.load(out / "agent_errors.npz")
    assert agents["dgtd/last"].shape == (len(agents["dgtd/steps"]), 2, 5)
    assert agents["td0/last"].shape[2] == 1  # one centralised estimate
    worst = [
        float(r["value"]) for r in rows if r["algorithm"] == "dgtd" and r["metric"] == "error_last" and r["seed"] == "1"
    ]
    np.testing.assert_allclose(worst, agents["dgtd/last"][:, 1].max(axis=1))


@pytest.mark.parametrize(
    "args, message",
    [
        (["compare", "baird", "--algorithms", "dgtd,td1"], "unknown algorithm"),
        (["compare", "bairds"], "did you mean 'baird'"),
        (["compare", "baird", "--algorithms", "td0,td0"], "named twice"),
    ],
)
def test_cli_compare_bad_input_is_one_line_and_exit_code_2(args, message, tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "dgtd.cli", *args, "--out", str(tmp_path / "x"), "--no-progress"],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and message in proc.stderr and "Traceback" not in proc.stderr


def _benchmark_module():
    import importlib.util
    from pathlib import Path

    path = Path(__file__).parents[2] / "benchmarks" / "time_to_accuracy.py"
    spec = importlib.util.spec_from_file_location("time_to_accuracy", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_time_to_accuracy_counts_per_seed_from_when_the_error_stays_below():
    mod = _benchmark_module()
    x = np.array([[10, 10], [20, 20], [30, 30], [40, 40]], dtype=float)
    Y = np.array([[1.0, 1.0], [0.05, 0.05], [0.2, 0.05], [0.05, 0.01]])
    # seed 0 rises above 0.1 at 30, so it counts from 40; seed 1 stays below from 20
    assert mod.first_stay_below(x, Y, 0.1).tolist() == [40.0, 20.0]
    assert mod.first_stay_below(x, Y, 0.001).tolist() == [np.inf, np.inf]
    Y_div = np.array([[1.0, 1.0], [0.05, np.nan], [0.05, np.nan], [0.05, np.nan]])
    assert mod.first_stay_below(x, Y_div, 0.1).tolist() == [20.0, np.inf]  # a diverged seed never gets there
    assert mod.band(np.array([20.0, np.inf]))[0] == np.inf  # half the seeds did not: no median
    med, lo, hi = mod.band(np.arange(21.0))
    assert (med, lo, hi) == (10.0, 1.0, 19.0)


def test_time_to_accuracy_script_writes_table_json_and_plot(tmp_path):
    from pathlib import Path

    script = Path(__file__).parents[2] / "benchmarks" / "time_to_accuracy.py"
    proc = subprocess.run(
        [
            sys.executable,
            str(script),
            "--tasks",
            "boyan",
            "--algorithms",
            "dgtd,td0",
            "--seeds",
            "2",
            "--iterations",
            "3000",
            "--out",
            str(tmp_path),
            "--no-docs",
        ],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 0, proc.stderr
    table = (tmp_path / "time_to_accuracy.md").read_text()
    assert "| boyan | dgtd |" in table and "| boyan | td0 |" in table and "Measured" in table
    rows = json.loads((tmp_path / "time_to_accuracy.json").read_text())["rows"]
    assert {r["algorithm"] for r in rows} == {"dgtd", "td0"}
    assert all(r["output"] in ("last", "tail") and len(r["samples_to_10%"]) == 3 for r in rows)
    assert (tmp_path / "time_to_accuracy.png").stat().st_size > 10_000


def test_dgtd_run_reports_a_diverged_baseline_and_writes_its_files(tmp_path, capsys):
    """`dgtd run baird --algorithm td0`: off-policy TD(0) diverges; the run says so and still writes every file."""
    out = tmp_path / "td0"
    main(
        [
            "run",
            "baird",
            "--algorithm",
            "td0",
            "-T",
            "30000",
            "--alpha0",
            "1",
            "--seeds",
            "2",
            "--out",
            str(out),
            "--no-progress",
        ]
    )
    text = capsys.readouterr().out
    assert "DIVERGED: seed(s) [0, 1]" in text
    for name in ("summary.json", "metrics.csv", "iterates.png", "errors.png"):
        assert (out / name).exists()


def test_compare_on_a_users_problem_file(run_cli, tmp_path):
    """`dgtd compare --problem FILE --graph --edge-prob`, as `dgtd run` takes them: every algorithm on the file's model
    and the network asked for, each at garnet's tuned steps scaled to the problem's features."""
    from dgtd.problems.generators import random_problem
    from dgtd.problems.io import save_problem

    path = tmp_path / "mine.npz"
    save_problem(str(path), random_problem(6, 4, 3, np.random.default_rng(5), gamma=0.8))
    out = tmp_path / "c"
    code, text, err = run_cli(
        "compare",
        "--problem",
        path,
        "--graph",
        "complete",
        "--edge-prob",
        0.5,
        "-a",
        "dgtd,td-tracking",
        "--seeds",
        2,
        "-T",
        3000,
        "--out",
        out,
        "--no-progress",
        "--no-plots",
    )
    assert code == 0, err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["config"]["problem_file"] == str(path.resolve()) and summary["config"]["graph"] == "complete"
    assert set(summary["algorithms"]) == {"dgtd", "td-tracking"}
    assert "network: complete" in text and "p=0.5" in text


def test_compare_tells_when_each_runs_kernels_are_ready():
    """So that `dgtd compare`'s progress bar leaves each compilation out of its rate (its first ETA read 143 hours)."""
    from dgtd.run.compare import CompareSettings, compare
    from dgtd.run.loop import RunSettings
    from dgtd.scenarios import get_scenario

    sc = get_scenario("paper-example-1")
    names = ("td0", "dgtd")
    ready = []
    compare(
        sc.problem,
        sc.network,
        sc.sampling,
        {n: make_algorithm(n, alpha0=0.1) for n in names},
        CompareSettings(names, RunSettings(iterations=10)),
        kernel_ready=ready.append,
    )
    assert len(ready) == len(names) and all(s >= 0 for s in ready)


def test_compare_figures_say_what_they_draw(run_cli, tmp_path, monkeypatch):
    """compare.png's legend draws each algorithm as its curves are drawn and says which iterate; no consensus.png
    when only centralised learners are compared (it was an empty figure)."""
    import dgtd.plots

    figures = []
    real = dgtd.plots._save
    monkeypatch.setattr(dgtd.plots, "_save", lambda fig, path: (figures.append(fig), real(fig, path)))
    import dgtd.plots.compare

    monkeypatch.setattr(dgtd.plots.compare, "_save", dgtd.plots._save)
    out = tmp_path / "c"
    code, text, err = run_cli(
        "compare", "paper-example-1", "-a", "td0,gtd2", "--seeds", 1, "-T", 300, "--out", out, "--no-progress"
    )
    assert code == 0, err
    assert (out / "compare.png").exists() and not (out / "consensus.png").exists()
    assert "consensus.png" not in text
    fig = figures[0]
    legend = fig.legends[0]
    assert [t.get_text() for t in legend.get_texts()] == ["td0", "gtd2", "sends nothing: its final level (right)"]
    assert [h.get_linestyle() for h in legend.legend_handles] == ["-", "-", ":"]
    assert "last iterate" in fig.axes[0].get_ylabel()


def test_error_area_is_the_mean_error_over_steps_and_a_diverged_seed_counts_as_not_learning():
    """Checkpoints at steps 10, 20, 100 of a 100-step run, each error held over the steps up to it: seed 0 learns
    (0.5 for 10 steps, 0.2 for 10, 0.1 for 80: area 0.05 + 0.02 + 0.08 = 0.15); seed 1 rises past the start's error
    (capped at 1) and diverges at step 20 (NaN from there): 1 for every step, area 1; seed 2 diverges at step 15
    after 0.4: 0.4 over steps 1..10, then 1 (the start's error) over the other 90: area 0.94."""
    from types import SimpleNamespace

    from dgtd.run.compare import error_area

    nan = float("nan")
    errors = np.array([[0.5, 3.0, 0.4], [0.2, nan, nan], [0.1, nan, nan]])
    result = SimpleNamespace(
        steps=np.array([10, 20, 100]),
        metrics={"value_error_last": errors},
        info={"diverged_at": np.array([-1, 20, 15])},
    )
    np.testing.assert_allclose(error_area(result), [0.15, 1.0, 0.94], rtol=1e-12)


def test_a_comparison_over_lossy_links_says_where_each_method_converges(run_cli, tmp_path):
    """Loss by receiver: DGTD and consensus TD(0) each have their own fixed point (Laplacian and Metropolis mixing),
    both about 47 % from w*, and summary.json gives each with its distance; --reweight brings DGTD's back to w*."""
    args = ("compare", "paper-example-1", "-a", "dgtd,consensus-td0", "-T", 500, "--seeds", 1, "--no-plots")
    lossy = ("--loss", "0.1,0.5,0,0.8,0.3")
    code, _, err = run_cli(*args, *lossy, "--out", tmp_path / "a", "--no-progress")
    assert code == 0, err
    algs = json.loads((tmp_path / "a" / "summary.json").read_text())["algorithms"]
    assert algs["dgtd"]["w_fixed"] != algs["consensus-td0"]["w_fixed"]
    assert all(0.4 < algs[n]["w_fixed_value_distance"] < 0.55 for n in algs)
    code, _, err = run_cli(*args, *lossy, "--reweight", "--out", tmp_path / "b", "--no-progress")
    assert code == 0, err
    algs = json.loads((tmp_path / "b" / "summary.json").read_text())["algorithms"]
    assert algs["dgtd"]["w_fixed_value_distance"] == 0.0 and algs["consensus-td0"]["w_fixed_value_distance"] > 0.4
