"""DGTD's first step from the problem (`dgtd.algorithms.dgtd.DGTD.first_step`, `from_the_problem`): half the largest
step at which every mode of its mean dynamics contracts, checked against the dynamics themselves, and a user's
problem file whose default steps swing run without the swing."""

from __future__ import annotations

import numpy as np

import dgtd
from dgtd.algorithms import DGTD
from dgtd.graphs import topologies
from dgtd.graphs.random import random_edges
from dgtd.problems import exact
from dgtd.problems.model import make_problem


def chain(n_states=10, n_agents=6):
    """A user's chain: a reflecting random walk, features [1, x, cos(pi x)] (correlated), rewards uniform in [0, 1]."""
    S = n_states
    P = np.zeros((S, S))
    for s in range(S):
        P[s, max(s - 1, 0)] += 0.5
        P[s, min(s + 1, S - 1)] += 0.5
    x = np.linspace(0.0, 1.0, S)
    R = np.random.default_rng(1).uniform(0.0, 1.0, (n_agents, S))
    return make_problem(P, R, np.stack([np.ones(S), x, np.cos(np.pi * x)], 1), 0.9, name="chain")


def test_the_step_is_half_the_largest_at_which_every_mode_contracts():
    """The mean iteration x <- (I - alpha G) x over every Laplacian mode: at the rule's alpha and up to 1.9 times it
    every mode contracts (max |1 - alpha nu| < 1); at twice it one mode no longer does (factor 1)."""
    p = chain()
    m = exact.Moments(p)
    L = random_edges(topologies.ring(6), 1.0).mean_laplacian()
    alpha = exact.fastest_contracting_step(m, L, 3.0)

    def worst(a):
        factors = []
        for lam in np.linalg.eigvalsh(L):
            nu = np.linalg.eigvals(exact.dgtd_mean_dynamics(m, lam, 3.0))
            factors.append(np.abs(1 - a * nu[nu.real > 1e-12]).max())
        return max(factors)

    assert worst(alpha) < 1 and worst(1.9 * alpha) < 1 and worst(2.0 * alpha) > 1 - 1e-9
    assert 0.1 < alpha < 0.2  # measured 0.139, against the default first step 10 / sqrt(1001) = 0.316


def test_a_problem_whose_default_steps_swing_runs_without_the_swing():
    """The chain above on a ring of 6: with the default steps 10 / sqrt(k + 1000) its worst agent's weight error
    reaches 118 times |w*| and the consensus error 8e6 within 300 steps (measured); with the offset from the problem
    (beta 5 170, first step 0.139) neither exceeds its start (error 1, consensus 0.1), and after 200 000 steps its
    tail average is nearer w* (measured value errors 0.13 % against 0.61 %, 4 seeds). Here 3 000 steps, 2 seeds:
    the swing and its absence."""
    p = chain()
    net = random_edges(topologies.ring(6), 1.0)
    default = DGTD()
    derived, note = default.from_the_problem(exact.Moments(p), net)
    assert derived.beta == 5170.0 and "first step 0.139" in note
    swings, calm = (dgtd.evaluate(p, net, alg, iterations=3000, seeds=2, checkpoints=100) for alg in (default, derived))
    assert np.nanmax(swings.metrics["error_last"]) > 10 and np.nanmax(swings.metrics["consensus"]) > 1e3
    assert np.nanmax(calm.metrics["error_last"]) <= 1.0 + 1e-9 and np.nanmax(calm.metrics["consensus"]) < 0.1


def test_a_problem_file_run_takes_its_steps_from_the_problem_and_says_so(tmp_path, run_cli):
    """`dgtd run --problem FILE` with no step option: the header names the offset and why; --beta keeps the user's."""
    p = chain()
    np.savez(tmp_path / "chain.npz", P=p.P, R=p.R, Phi=p.Phi, gamma=p.gamma)
    command = ("run", "--problem", tmp_path / "chain.npz", "-T", "200", "--no-plots", "--no-progress")
    code, text, err = run_cli(*command, "--out", tmp_path / "a")
    assert code == 0, err
    assert "alpha_k = 10/sqrt(k+5170)" in text and "steps from the problem: the offset beta 5170" in text
    code, text, err = run_cli(*command, "--beta", "1000", "--out", tmp_path / "b")
    assert code == 0 and "alpha_k = 10/sqrt(k+1000)" in text and "steps from the problem" not in text


def test_dgtd_compare_on_a_problem_file_says_where_dgtds_offset_comes_from(tmp_path, run_cli):
    """`dgtd compare --problem FILE` runs DGTD at the offset `dgtd run` takes from the problem, and says so beside
    its alpha0 (it printed the other methods' origin, garnet's steps, for it too)."""
    p = chain()
    np.savez(tmp_path / "chain.npz", P=p.P, R=p.R, Phi=p.Phi, gamma=p.gamma)
    code, text, err = run_cli(
        "compare",
        "--problem",
        tmp_path / "chain.npz",
        "-a",
        "dgtd,td0",
        "-T",
        "200",
        "--seeds",
        "1",
        "--no-plots",
        "--no-progress",
        "--out",
        tmp_path / "c",
    )
    assert code == 0, err
    assert "dgtd 10 (offset 5170 from the problem)" in text
