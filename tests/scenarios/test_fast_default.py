"""DGTD's default step sizes (10 / sqrt(k + 1000), kappa 3; on a problem file the offset from the problem), what
`dgtd run` uses without step-size options, and the rate of its tail average (docs/benchmarks.md has the
time-to-accuracy table behind the choice)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from dgtd.algorithms import DGTD
from dgtd.graphs import topologies
from dgtd.graphs.random import random_edges
from dgtd.problems import exact
from dgtd.run.loop import RunSettings, run
from dgtd.scenarios import get_scenario


def test_dgtd_run_uses_the_fast_defaults_and_the_paper_example_keeps_the_papers(run_cli, tmp_path):
    from dgtd.problems.io import save_problem

    garnet = get_scenario("garnet").problem
    save_problem(tmp_path / "p.npz", garnet)
    # a problem file's offset comes from the problem (`DGTD.from_the_problem`), on its default network (ring, p = 1)
    derived = DGTD().from_the_problem(exact.Moments(garnet), random_edges(topologies.ring(10), 1.0))[0].beta
    assert derived > 1000.0
    for args, expected in (
        ((("--problem", tmp_path / "p.npz")), (10.0, derived, 3.0)),
        (("boyan",), (10.0, 1000.0, 3.0)),
        (("paper-example-1",), (10.0, 100.0, 1.0)),
    ):
        out = tmp_path / args[-1].__str__().replace("/", "_")
        code, _, err = run_cli("run", *args, "-T", "100", "--no-plots", "--no-progress", "--out", out)
        assert code == 0, err
        config = json.loads((out / "summary.json").read_text())["config"]
        assert (config["alpha0"], config["beta"], config["kappa"], config["schedule"]) == (*expected, "sqrt"), args
    assert (DGTD().alpha0, DGTD().beta, DGTD().kappa) == (10.0, 1000.0, 3.0)


@pytest.mark.slow
def test_the_tail_average_error_falls_like_one_over_sqrt_t():
    """With alpha_k = alpha0 / sqrt(k + beta) the tail average's error falls like T^(-1/2) (Polyak-Ruppert).

    Example 1 with DGTD's defaults, 16 seeds at each T = 2e4, 8e4, 3.2e5, 1.28e6: the log-log slope of the RMS over
    seeds of the worst agent's value error of the tail average was -0.51 (boyan -0.46, garnet -0.53). Tolerance
    [-0.7, -0.35]: about four times the slope's spread between base seeds, and it excludes both a stalled run
    (slope 0) and a mistaken T^(-1) claim."""
    sc = get_scenario("paper-example-1")
    m = exact.Moments(sc.problem)
    Ts = np.array([20_000, 80_000, 320_000, 1_280_000])
    rms = []
    for T in Ts:
        r = run(
            sc.problem, sc.network, DGTD(), sc.sampling, RunSettings(iterations=int(T), seeds=16, seed=7, checkpoints=2)
        )
        e = exact.value_error(m, r.w_tail, r.w_star).max(-1)
        rms.append(np.sqrt(np.mean(e**2)))
    slope = np.polyfit(np.log(Ts), np.log(rms), 1)[0]
    assert -0.7 < slope < -0.35, (slope, rms)
