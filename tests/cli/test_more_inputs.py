"""More inputs of the classes a new user met (learning options, link and graph options, problem files, seeds and
counts), written after those were mended: each is one line and exit 2 naming what is wrong, or a correct run."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers import one_line_error


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A valid 2-agent, 3-state team MDP file and one file for each way of spoiling it."""
    folder = tmp_path_factory.mktemp("files")
    rng = np.random.default_rng(0)
    S = 3
    P, R = rng.dirichlet(np.ones(S), size=(S, 4)), rng.uniform(0, 1, (2, S, 4))
    good = {"P": P, "R": R, "Phi": np.eye(S), "gamma": 0.5, "policy_0": np.full((S, 2), 0.5)}
    good["policy_1"] = good["policy_0"]
    spoiled = {
        "good": {},
        "p_rows": {"P": P * 1.1},
        "r_agents": {"R": R[:1]},
        "neg_policy": {"policy_0": np.array([[1.5, -0.5]] * S)},
        "gamma": {"gamma": 1.5},
        "phi_rank": {"Phi": np.zeros((S, 2))},
        "phi_rows": {"Phi": np.eye(S)[:2]},
        "r_inf": {"R": np.full_like(R, np.inf)},
    }
    for name, change in spoiled.items():
        np.savez(folder / f"{name}.npz", **(good | change))
    arrays = dict(good)
    del arrays["policy_1"]
    np.savez(folder / "missing_policy.npz", **arrays)
    (folder / "notnpz.npz").write_text("hello")
    return folder


REFUSED = [
    (["learn", "pull-away", "--actor-step", "-1"], ["actor's steps", "step > 0", "-1.0"]),
    (["learn", "pull-away", "--actor-step", "nan"], ["actor's steps", "nan"]),
    (["learn", "pull-away", "--actor-offset", "0"], ["offset > 0"]),
    (["learn", "pull-away", "--actor-power", "1.5"], ["power in (0, 1]", "1.5"]),
    (["learn", "pull-away", "--entropy", "-0.1"], ["entropy bonus", "-0.1"]),
    (["learn", "pull-away", "--entropy", "inf"], ["entropy bonus", "inf"]),
    (["learn", "pull-away", "--actor-warmup", "-3"], ["warm-up", "-3"]),
    (["learn", "pull-away", "--batch", "0"], ["batch", ">= 1"]),
    (["learn", "pull-away", "--seeds", "0"], ["seeds", ">= 1"]),
    (["learn", "pull-away", "--checkpoints", "0"], ["checkpoints", ">= 1"]),
    (["learn", "pull-away", "-T", "0"], ["iterations", ">= 1"]),
    (["learn", "pull-away", "--values", "both"], ["--values", "both"]),
    (["learn", "pull-away", "--objective", "total"], ["--objective", "total"]),
    (["learn", "pull-away", "--states", "0"], ["1 state"]),
    (["learn", "pull-away", "--agents", "2.5"], ["--agents", "2.5"]),
    (["learn", "factored", "--agents", "3"], ["multiple of its groups' 2", "3"]),
    (["learn", "zhang-20", "--agents", "3"], ["multiple of its groups' 2"]),
    (["learn", "pull-away", "--from", "/nonexistent"], ["/nonexistent", "missing"]),
    (["learn", "pull-away", "--from-seed", "1"], ["--from-seed", "--from DIR"]),
    (["learn", "pull-away", "--loss", "1.0"], ["loss", "[0, 1)"]),
    (["learn", "pull-away", "--loss", "-0.1"], ["loss", "-0.1"]),
    (["learn", "pull-away", "--edge-prob", "0"], ["disconnected"]),
    (["learn", "pull-away", "--edge-prob", "1.5"], ["edge probabilities", "1.5"]),
    (["learn", "pull-away", "--graph", "nosuch"], ["nosuch", "small-world"]),
    (["learn", "pull-away", "--algorithm", "td0"], ["td0 is one centralised learner", "consensus-td0"]),
    (["learn", "pull-away", "--alpha0", "-1"], ["alpha0", "positive"]),
    (["learn", "pull-away", "--schedule", "weird"], ["--schedule", "weird"]),
    (["learn", "pull-away", "--delay", "-1"], ["delay", "-1"]),
    (["learn", "pull-away", "--bits", "0"], ["bits", "[1, 64]"]),
    (["learn", "pull-away", "--top-k", "0"], ["top_k", ">= 1"]),
    (["learn", "pull-away", "--wake", "0"], ["wake", "(0, 1]"]),
    (["learn", "pull-away", "--team-reward", "neighbourhood", "--bits", "8"], ["neighbourhood", "compress"]),
    (["learn", "mpe-spread", "--states", "3"], ["simulator", "--states"]),
    (["learn", "pull-away", "--seed", "-1"], ["seed", ">= 0", "-1"]),  # (a ValueError traceback from the streams)
    (["learn", "pull-away", "--checkpoint-every", "-5"], ["checkpoint_every", "-5"]),  # (it ran, saving nothing)
    (["learn", "pull-away", "--burst", "0.5", "--loss", "0.2"], ["burst", "0.5"]),
    (["learn", "pull-away", "--log", "wandb"], ["log", "wandb"]),
    (["learn", "pull-away", "--graph", "small-world", "--rewire", "2"], ["rewiring probability", "2.0"]),
    (["learn", "pull-away", "--graph", "sparse-random", "--mean-degree", "0"], ["--mean-degree", "sparse-random"]),
    (["run", "garnet", "--agents", "10", "--graph", "small-world", "--rewire", "-1"], ["rewiring probability"]),
    (["run", "garnet", "--agents", "10", "--graph", "sparse-random", "--mean-degree", "0"], ["(0, 9] on 10 agents"]),
    (["compare", "pull-away", "--seeds", "0"], ["seeds", ">= 1"]),
]

FILES = [
    ("missing", ["missing"]),
    ("p_rows", ["row 0 of P(s, a, .)", "1.1"]),
    ("r_agents", ["2 policies for 1 agents"]),
    ("neg_policy", ["policy 0", "negative"]),
    ("gamma", ["gamma", "1.5"]),
    ("phi_rank", ["Phi", "full column rank"]),
    ("phi_rows", ["Phi", "(2, 3)"]),
    ("missing_policy", ["1 policies for 2 agents"]),
    ("r_inf", ["NaN or infinite", "agent 0, state 0"]),
    ("notnpz", ["cannot be read", "not an .npz"]),
]


def _run(run_cli, tmp_path, args):
    return run_cli(*args, *([] if "-T" in args else ["-T", 10]), "--no-progress", "--out", tmp_path / "o")


@pytest.mark.parametrize("args, words", REFUSED)
def test_a_bad_option_is_one_line(run_cli, tmp_path, args, words):
    one_line_error(*_run(run_cli, tmp_path, args), *words)


@pytest.mark.parametrize("name, words", FILES)
def test_a_bad_learning_file_is_one_line(run_cli, tmp_path, files, name, words):
    one_line_error(*_run(run_cli, tmp_path, ["learn", "--problem", files / f"{name}.npz"]), *words)


@pytest.mark.parametrize(
    "args",
    [
        ["learn", "delayed-reward", "--agents", "1"],  # one agent advancing alone: a single-agent MDP
        ["learn", "pull-away", "--graph", "small-world"],  # (k = 4 by default was refused on 4 agents: now k = 2)
        ["learn", "pull-away", "--checkpoint-every", "5"],
    ],
)
def test_an_edge_case_runs_and_says_what_it_did(run_cli, tmp_path, args):
    code, out, err = _run(run_cli, tmp_path, [*args, "--no-plots"])
    assert code == 0, err
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert len(summary["return_last"]) == 2 and all(np.isfinite(summary["return_last"]))


def test_a_learning_runs_policies_refused_where_missing(run_cli, tmp_path, files):
    one_line_error(
        *run_cli("run", "--problem", files / "good.npz", "--policies", tmp_path / "none", "-T", 10, "--out", tmp_path),
        "policies", "missing",
    )  # fmt: skip
