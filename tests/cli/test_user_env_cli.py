"""`dgtd run --env module:make_env` and `--data FILE`: the user's own simulator or recordings from the command line
and from an experiment file's [env] table; bad input is one line and exit code 2."""

from __future__ import annotations

import json

import numpy as np
import pytest

from dgtd.config import make_source, resolve, unflat, view


def test_a_scenarios_source_is_built_with_the_runs_parameters(monkeypatch):
    """make_source must build the scenario with the spec's params, not the scenario's defaults."""
    import dgtd.scenarios as scenarios

    seen = []

    def toy(size: int = 3):
        seen.append(size)
        sc = scenarios.garnet_scenario()
        from dataclasses import replace

        return replace(sc, source=lambda seed, ids: ("source of size", size))

    monkeypatch.setitem(scenarios.SCENARIOS, "toy", toy)
    _, _, _, _, settings, resolved, _ = resolve(unflat(dict(scenario="toy", params={"size": 7}, iterations=10)))
    assert make_source(resolved, settings) == ("source of size", 7)


pytest.importorskip("pettingzoo", reason="the environment extra (pip install dgtd[envs]) is not installed")

from pathlib import Path  # noqa: E402

from envs import chain  # noqa: E402
from helpers import one_line_error  # noqa: E402

from dgtd.problems import exact  # noqa: E402
from dgtd.problems.model import make_problem  # noqa: E402

ENVS = Path(__file__).resolve().parents[1] / "envs" / "chain.py"


def env(name: str) -> str:
    return f"{ENVS}:{name}"


def summary(out) -> dict:
    return json.loads((Path(out) / "summary.json").read_text())


def test_run_on_a_users_parallel_env_reaches_its_exact_w_star(run_cli, tmp_path):
    """`dgtd run --env FILE.py:make_chain --features one-hot --agents 4`: the LSTD reference (8 x 5,000 transitions)
    within 4 standard errors of the exact w* of the chain's model (4 sigma: a false alarm once in 16,000 runs per
    weight), and DGTD's tail average within 3 % of the reference in value error (it ends near 1 %)."""
    out = tmp_path / "chain"
    code, text, err = run_cli(
        "run",
        "--env",
        env("make_chain"),
        "--features",
        "one-hot",
        "--agents",
        4,
        "--gamma",
        chain.GAMMA,
        "-T",
        30_000,
        "--seeds",
        2,
        "--out",
        out,
        "--no-plots",
        "--no-progress",
    )
    assert code == 0, err
    assert "w* is estimated (no model)" in text and "one-hot features of 4 states" in text
    s = summary(out)
    w = exact.w_star(exact.Moments(make_problem(chain.P, chain.R, np.eye(4), chain.GAMMA)))
    ref = s["reference"]
    assert np.all(np.abs(np.array(s["w_star"]) - w) <= 4 * np.array(ref["w_star_stderr"]))
    # the centralised TD(0) check on the same 40,000 transitions agrees (measured 0.17 %)
    assert ref["td_check_transitions"] == 40_000 and ref["td_check_value_gap"] < 0.01
    assert np.max(s["value_error_tail"]) < 0.03
    config = (out / "config.toml").read_text()
    assert "[problem.env]" in config and 'features = "one-hot"' in config and "agents = 4" in config
    code, _, err = run_cli("run", out / "config.toml", "--out", tmp_path / "again", "--no-plots", "--no-progress")
    assert code == 0, err
    assert (tmp_path / "again" / "metrics.csv").read_bytes() == (out / "metrics.csv").read_bytes()


def test_an_env_table_in_an_experiment_file_is_the_same_run_as_the_flags(run_cli, tmp_path):
    file = tmp_path / "chain.toml"
    file.write_text(
        f'gamma = 0.8\niterations = 2000\n\n[env]\nmake = "{env("make_chain")}"\nfeatures = "one-hot"\n'
        'policy = "random"\n'
    )
    a, b = tmp_path / "a", tmp_path / "b"
    assert run_cli("run", file, "--out", a, "--no-plots", "--no-progress")[0] == 0
    assert (
        run_cli(
            "run",
            "--env",
            env("make_chain"),
            "--features",
            "one-hot",
            "--gamma",
            0.8,
            "-T",
            2000,
            "--out",
            b,
            "--no-plots",
            "--no-progress",
        )[0]
        == 0
    )
    assert (a / "metrics.csv").read_bytes() == (b / "metrics.csv").read_bytes()


def test_a_gymnasium_envs_reward_split_among_agents_averages_to_its_reward():
    import gymnasium

    from dgtd.sources.gym import SplitReward

    for split in ("random", [0.5, 0.3, 0.2]):
        env = SplitReward(gymnasium.make("CartPole-v1"), 3, split)
        env.reset(seed=0)
        shares = []
        for _ in range(20):
            _, rewards, terms, truncs, _ = env.step({a: 0 for a in env.agents})
            r = np.array(list(rewards.values()))
            assert np.isclose(r.mean(), 1.0)  # CartPole's reward is 1 at every step
            shares.append(r / 3)
            if any(terms.values()):
                env.reset(seed=1)
        shares = np.array(shares)
        assert np.allclose(shares, [0.5, 0.3, 0.2]) if split != "random" else shares.std(axis=0).min() > 0.05


def test_run_on_a_gymnasium_env_split_among_three_agents(run_cli, tmp_path):
    """CartPole under the random policy, its reward split at random among 3 agents on a ring: each agent's tail
    average within 20 % of the estimated reference after 20,000 steps (measured 13.1 %, and 9.0 % after 80,000: the
    Fourier weights are ill-conditioned here, their standard error 13 % of |w*|, so gradient TD is slow)."""
    out = tmp_path / "cartpole"
    code, text, err = run_cli(
        "run",
        "--env",
        "gymnasium:CartPole-v1",
        "--agents",
        3,
        "--features",
        "fourier:1",
        "-T",
        20_000,
        "--out",
        out,
        "--no-plots",
        "--no-progress",
    )
    assert code == 0, err
    assert "Gymnasium env gymnasium:CartPole-v1, 3 agents, fourier features (16)" in text
    assert np.max(summary(out)["value_error_tail"]) < 0.20


def record_parquet(path, seeds=4, steps=10_000):
    import pyarrow as pa
    import pyarrow.parquet as pq
    from helpers import record

    from dgtd.problems.tasks import garnet

    problem = garnet(n_states=8, branching=3, n_agents=3, n_features=3, seed=1)
    pq.write_table(pa.table(record(problem, seeds=seeds, steps=steps)), path)
    return problem


def test_run_on_recorded_transitions_reaches_the_models_w_star(run_cli, tmp_path):
    """`dgtd run --data FILE.parquet`: each recording a seed, the reference within 4 standard errors of the model's
    w*, DGTD within 3 % of the reference."""
    problem = record_parquet(tmp_path / "t.parquet")
    out = tmp_path / "data"
    code, text, err = run_cli(
        "run",
        "--data",
        tmp_path / "t.parquet",
        "--gamma",
        problem.gamma,
        "--seeds",
        2,
        "--out",
        out,
        "--no-plots",
        "--no-progress",
    )
    assert code == 0, err
    s = summary(out)
    assert s["config"]["iterations"] == 10_000  # the recordings' length
    w = exact.w_star(exact.Moments(problem))
    assert np.all(np.abs(np.array(s["w_star"]) - w) <= 4 * np.array(s["reference"]["w_star_stderr"]))
    assert np.max(s["value_error_tail"]) < 0.03


def test_a_data_run_draws_its_links_from_the_networks_edge_probability(run_cli, tmp_path):
    """`dgtd run --data FILE --edge-prob 0.5` sends about half the messages of `--edge-prob 1` (the recordings hold no
    links: every link was up at every step before), and reaches the same reference. 2 seeds x 10,000 steps x 3 links:
    the fraction's standard error is 0.5 / sqrt(60,000) = 0.002, so 0.01 is 5 of them."""
    problem = record_parquet(tmp_path / "t.parquet", seeds=2)
    sent = {}
    for p in (1.0, 0.5):
        out = tmp_path / f"p{p}"
        code, _, err = run_cli(
            "run",
            "--data",
            tmp_path / "t.parquet",
            "--gamma",
            problem.gamma,
            "--seeds",
            2,
            "--edge-prob",
            p,
            "--out",
            out,
            "--no-plots",
            "--no-progress",
        )
        assert code == 0, err
        s = summary(out)
        sent[p] = np.sum(s["messages"])
        assert np.max(s["value_error_tail"]) < 0.03
    assert abs(sent[0.5] / sent[1.0] - 0.5) < 0.01, sent


BAD = [
    (["--env", "no_such_module:make"], ["cannot import no_such_module"]),
    (["--env", env("make_nothing")], ["neither a PettingZoo ParallelEnv"]),
    (["--env", env("make_nan_chain"), "--features", "one-hot"], ["NaN or infinite states"]),
    (["--env", env("make_chain"), "--features", env("widening_features")], ["wide, not"]),
    (["--env", env("make_chain"), "--features", "fourier:x"], ["write fourier:N"]),
    (["--env", env("make_chain"), "--features", "wavelets"], ["'wavelets' is not known"]),
    (["--env", env("make_chain"), "--policy", env("no_policy")], ["has no no_policy"]),
    (["--env", "gymnasium:CartPole-v1"], ["give --agents N"]),
    (["--env", "gymnasium:CartPole-v1", "--agents", "1"], ["at least 2"]),
    (["--env", "gymnasium:CartPole-v1", "--agents", "2", "--split", "0.5,0.6"], ["sum to 1"]),
    (["--env", "gymnasium:CartPole-v1", "--agents", "3", "--split", "0.5,0.5"], ["3 shares"]),
    (["--env", env("make_chain"), "--split", "0.5,0.3,0.2"], ["--split", "ParallelEnv", "own rewards"]),
    (["--env", env("make_old_gym"), "--agents", "2"], ["old Gym API", "reset()", "(observation, info)"]),
    (["--env", env("make_old_parallel")], ["old", "API", "reset()", "(observations, infos)"]),
    (["--env", env("make_text_chain"), "--features", "fourier:2"], ["(TextChain) returned 'state", "not real"]),
    (["--env", "gymnasium:NoSuchEnv-v0", "--agents", "2"], ["gymnasium cannot make"]),
    (["--env", env("make_chain"), "--agents", "2", "--gamma", "1.5"], ["gamma must be in [0, 1]"]),
    (["--env", env("make_chain"), "paper-example-1"], ["exactly one problem"]),
    (["paper-example-1", "--gamma", "0.5"], ["gamma is the discount of an --env or --data run"]),
    (["--data", "missing.parquet"], ["is missing"]),
    (["paper-example-1", "--features", "fourier:2"], ["features set the fields of an env run", "--env"]),
    (["paper-example-1", "--policy", "random"], ["has no parameter 'policy'"]),
]


@pytest.mark.parametrize("args, words", BAD, ids=[" ".join(a)[-40:] for a, _ in BAD])
def test_bad_env_input_is_one_line(run_cli, tmp_path, args, words):
    one_line_error(*run_cli("run", *args, "-T", 100, "--out", tmp_path / "r", "--no-progress"), *words)
    assert not (tmp_path / "r" / "summary.json").exists()


def test_bad_data_runs_are_one_line(run_cli, tmp_path):
    record_parquet(tmp_path / "t.parquet", seeds=3, steps=50)
    for args, words in (
        (["--seeds", 4], ["holds 3 recordings", "--seeds 3"]),
        (["-T", 51], ["run at most --iterations 50"]),
    ):
        one_line_error(*run_cli("run", "--data", tmp_path / "t.parquet", *args, "--out", tmp_path / "r"), *words)
    (tmp_path / "bad.csv").write_text("seed,step,agent,phi_0,next_phi_0,reward\n0,0,one,1.0,1.0,0.5\n")
    one_line_error(
        *run_cli("run", "--data", tmp_path / "bad.csv", "--out", tmp_path / "r"), "column agent must hold integers"
    )
    (tmp_path / "short.csv").write_text("seed,step,agent,phi_0,reward\n0,0,0,1.0,0.5\n")
    one_line_error(
        *run_cli("run", "--data", tmp_path / "short.csv", "--out", tmp_path / "r"), "lacks the column(s) next_phi_0"
    )
    assert not (tmp_path / "r" / "summary.json").exists()


def test_an_unknown_env_field_names_the_closest(run_cli, tmp_path):
    file = tmp_path / "e.toml"
    file.write_text(f'[env]\nmake = "{env("make_chain")}"\nfeature = "one-hot"\n')
    one_line_error(
        *run_cli("run", file, "--out", tmp_path / "r"), "unknown field 'feature' in [env]", "did you mean 'features'?"
    )


def test_a_run_on_an_env_draws_every_agents_values_along_a_trajectory(run_cli, tmp_path):
    """values.png, and in summary.json each agent's RMS value error along that trajectory (measured 0.23 % at 30,000
    steps; 5 % is what an unconverged run exceeds)."""
    out = tmp_path / "chain"
    code, text, err = run_cli(
        "run",
        "--env",
        env("make_chain"),
        "--features",
        "one-hot",
        "--gamma",
        chain.GAMMA,
        "-T",
        30_000,
        "--out",
        out,
        "--no-progress",
    )
    assert code == 0, err
    assert (out / "values.png").stat().st_size > 10_000 and "values.png" in text
    numbers = summary(out)["scenario"]
    assert numbers["trajectory_steps"] == 200 and len(numbers["trajectory_value_error"]) == 3
    assert max(numbers["trajectory_value_error"]) < 0.05


def test_a_sweep_job_on_an_env_runs_on_the_envs_samples():
    """`dgtd sweep` jobs must take the scenario's own source, as `dgtd run` does, not sample a model."""
    from dgtd.config import make_source, resolve
    from dgtd.run.loop import run
    from dgtd.sweep import run_job

    spec = {"env": {"make": env("make_chain"), "features": "one-hot"}, "gamma": chain.GAMMA, "iterations": 2000}
    job = run_job(spec)
    problem, network, algorithm, sampling, settings, resolved, channel = resolve(unflat(dict(**spec)))
    direct = run(problem, network, algorithm, sampling, settings, source=make_source(resolved, settings))
    np.testing.assert_array_equal(job["metrics"]["value_error_tail"], direct.metrics["value_error_tail"])


def test_a_sweep_grid_can_vary_the_env_table():
    from dgtd.experiments import parse
    from dgtd.sweep import expand

    exp = parse(
        {
            "env": {"make": env("make_chain")},
            "gamma": 0.8,
            "iterations": 100,
            "grid": {"env": {"features": ["one-hot", "linear"]}, "alpha0": [1.0, 2.0]},
        }
    )
    jobs = expand(exp)
    assert len(jobs) == 4
    assert {view(job.config).env["features"] for job in jobs} == {"one-hot", "linear"}
    assert {job.point["env.features"] for job in jobs} == {"one-hot", "linear"}


def test_a_reward_mapping_in_the_env_table_gives_each_agent_its_mapped_reward(run_cli, tmp_path):
    """rewards = team_rewards gives every agent the sum of the chain's rewards, so w* is N x that of the average."""
    file = tmp_path / "team.toml"
    file.write_text(
        f'gamma = 0.8\niterations = 200\n\n[env]\nmake = "{env("make_chain")}"\nfeatures = "one-hot"\n'
        f'rewards = "{env("team_rewards")}"\n'
    )
    assert run_cli("run", file, "--out", tmp_path / "team", "--no-plots", "--no-progress")[0] == 0
    assert (
        run_cli(
            "run",
            "--env",
            env("make_chain"),
            "--features",
            "one-hot",
            "--gamma",
            0.8,
            "-T",
            200,
            "--out",
            tmp_path / "own",
            "--no-plots",
            "--no-progress",
        )[0]
        == 0
    )
    team, own = np.array(summary(tmp_path / "team")["w_star"]), np.array(summary(tmp_path / "own")["w_star"])
    np.testing.assert_allclose(team, 3 * own, rtol=1e-9)


def test_compare_runs_on_an_env_and_on_recordings(run_cli, tmp_path):
    """`dgtd compare --env ...` and `--data ...`: every algorithm on the same samples, the reference said to be an
    estimate in summary.json."""
    code, text, err = run_cli(
        "compare",
        "--env",
        env("make_chain"),
        "--features",
        "one-hot",
        "--gamma",
        0.8,
        "-a",
        "dgtd,td0",
        "-T",
        3000,
        "--seeds",
        2,
        "--out",
        tmp_path / "c",
        "--no-plots",
        "--no-progress",
    )
    assert code == 0, err
    s = summary(tmp_path / "c")
    assert s["reference"]["estimated"] and set(s["algorithms"]) == {"dgtd", "td0"}
    record_parquet(tmp_path / "t.parquet", seeds=2, steps=3000)
    code, text, err = run_cli(
        "compare",
        "--data",
        tmp_path / "t.parquet",
        "-a",
        "dgtd,gtd2",
        "--seeds",
        2,
        "--out",
        tmp_path / "d",
        "--no-plots",
        "--no-progress",
    )
    assert code == 0, err
    assert summary(tmp_path / "d")["config"]["iterations"] == 3000


def test_fourier_features_take_the_declared_box_or_the_range_seen():
    """CartPole declares finite bounds for 2 of its 4 variables: those are kept, the other 2 come from the pilot
    states; an env whose state() is not its observations gets its box from the states seen."""
    from dgtd.scenarios.user import EnvSpec, build_features, env_factory

    make, _, _ = env_factory(EnvSpec(make="gymnasium:CartPole-v1", agents=2))
    pilot = lambda steps=None: np.array([[0.0, -3.0, 0.0, -2.0], [0.1, 5.0, 0.1, 4.0]])  # noqa: E731
    f, q, about = build_features("fourier:1", make(), pilot)
    assert q == 16 and "range of 2 states seen" in about
    probe = make()
    bounds = probe.env.observation_space
    x = np.array([[bounds.low[0], -3.0, bounds.low[2], -2.0], [bounds.high[0], 5.0, bounds.high[2], 4.0]])
    np.testing.assert_allclose(f(x)[:, 1:], feature_maps_of_corners(), atol=1e-12)


def feature_maps_of_corners():
    """fourier:1 at the box's two corners, (0, 0, 0, 0) and (1, 1, 1, 1) scaled: cos(pi c.x) for c in {0,1}^4."""
    from itertools import product

    cs = np.array(list(product([0, 1], repeat=4)))[1:]
    return np.stack([np.ones(len(cs)), np.cos(np.pi * cs.sum(axis=1))])


def test_a_policy_per_agent_in_the_env_table(run_cli, tmp_path):
    file = tmp_path / "p.toml"
    table = (
        f'gamma = 0.8\niterations = 300\n\n[env]\nmake = "{env("make_chain")}"\nfeatures = "one-hot"\n\n[env.policy]\n'
    )
    file.write_text(table + f'agent_0 = "random"\nagent_1 = "{env("stay")}"\nagent_2 = "{env("stay")}"\n')
    code, text, err = run_cli("run", file, "--out", tmp_path / "p", "--no-plots", "--no-progress")
    assert code == 0, err
    assert "policy one per agent" in text and "[problem.env.policy]" in (tmp_path / "p" / "config.toml").read_text()
    file.write_text(table + 'agent_0 = "random"\nagent_7 = "random"\n')
    one_line_error(
        *run_cli("run", file, "--out", tmp_path / "q"),
        "must name every agent once",
        "missing agent_1, agent_2",
        "unknown agent_7",
    )


def test_the_trajectory_report_measures_each_result_not_the_first():
    """A scenario is built once per process (`dgtd.config.scenario_of`), so its report is called on every run's
    result: the trajectory is drawn once, but the values and errors must be each result's own."""
    from types import SimpleNamespace

    from dgtd.config import scenario_of

    resolved = resolve(unflat(dict(env={"make": env("make_chain"), "features": "one-hot"}, gamma=0.8))).config
    report = scenario_of(resolved).report
    w_star = scenario_of(resolved).problem.w_star
    exact_run = SimpleNamespace(w_star=w_star, w_tail=np.tile(w_star, (1, 3, 1)))
    off_run = SimpleNamespace(w_star=w_star, w_tail=np.tile(1.1 * w_star, (1, 3, 1)))
    assert max(report(exact_run, None)[0]["trajectory_value_error"]) < 1e-12
    assert np.allclose(report(off_run, None)[0]["trajectory_value_error"], 0.1)


def test_an_env_run_is_named_after_its_module_and_function_and_says_where_its_samples_come_from(run_cli, tmp_path):
    """A factory called make is named chain.make, not make (a results folder runs/make says nothing); the header
    says the samples are the simulator's, not 'iid sampling, independent states' (the Sampling's, unused here)."""
    out = tmp_path / "e"
    code, text, err = run_cli(
        "run", "--env", env("make_chain"), "--agents", 2, "-T", 200, "--out", out, "--no-plots", "--no-progress"
    )
    assert code == 0, err
    assert text.startswith("chain.make_chain: ")
    assert "iid sampling" not in text and "independent states" not in text
    assert "the simulator's samples" in text
    from dgtd.scenarios.user import env_name

    assert env_name("pkg.envs:make") == "envs.make" and env_name("gymnasium:CartPole-v1") == "CartPole-v1"
    assert env_name("/a/b/robots.py:make") == "robots.make"


def test_a_data_run_says_its_transitions_are_recorded_rows_not_independent(run_cli, tmp_path):
    """The reference's transitions are every agent's recorded rows, correlated along trajectories: only its groups
    (one per recording) are independent, and the header names the recording, not a sampling mode."""
    record_parquet(tmp_path / "t.parquet", seeds=2, steps=2_000)
    code, text, err = run_cli(
        "run", "--data", tmp_path / "t.parquet", "-T", 500, "--out", tmp_path / "d", "--no-plots", "--no-progress"
    )
    assert code == 0, err
    assert "independent transitions" not in text and "independent states" not in text and "iid sampling" not in text
    assert "12,000 transitions (along trajectories) in 2 independent groups" in text, text  # 2 x 2000 x 3 rows
    assert "the recording's samples" in text


def test_a_run_on_an_env_estimates_its_reference_once(run_cli, tmp_path, monkeypatch):
    """The reference (LSTD over 8 x 5,000 transitions) was estimated twice per `dgtd run --env`: once for the
    config's scenario, once more for the resolved config's, whose key named the default graph ("ring", p = 1) that
    the first left out."""
    import dgtd.sources.env
    from dgtd.config import _scenario

    calls = []
    estimate = dgtd.sources.env.reference_from_env
    monkeypatch.setattr(dgtd.sources.env, "reference_from_env", lambda *a, **k: calls.append(1) or estimate(*a, **k))
    _scenario.cache_clear()
    args = ("--env", env("make_chain"), "--features", "one-hot", "--agents", 4, "-T", 200, "--no-plots")
    code, _, err = run_cli("run", *args, "--no-progress", "--out", tmp_path / "a")
    assert code == 0, err
    assert len(calls) == 1


def test_an_env_run_takes_its_first_step_from_its_estimated_mean_dynamics(run_cli, tmp_path):
    """`dgtd run --env` with no step option: DGTD's first step from the mean dynamics of the reference's kept
    transitions (20 000 along trajectories, `MomentSums.kept_transitions`), said in the header; on the test chain it
    is within 2 % of the step from the chain's model (measured 0.139 both: the ring's consensus block binds), which
    a sampling error of about 1 / sqrt(20 000) in the moments allows. --beta keeps the user's."""
    from dgtd.algorithms import DGTD
    from dgtd.algorithms import mean_dynamics as md
    from dgtd.graphs import topologies
    from dgtd.graphs.random import random_edges

    args = ("--env", env("make_chain"), "--features", "one-hot", "--agents", 4, "-T", 200, "--no-plots")
    code, text, err = run_cli("run", *args, "--no-progress", "--out", tmp_path / "a")
    assert code == 0, err
    beta = float(text.split("steps from the problem: the offset beta ")[1].split(" ")[0])
    first = float(text.split("makes the first step ")[1].split(",")[0])
    model = exact.Moments(make_problem(chain.P, chain.R, np.eye(4), chain.GAMMA))
    exact_step = md.first_step(DGTD(), model, random_edges(topologies.ring(4), 1.0))[0]
    assert abs(first - exact_step) <= 0.02 * exact_step and f"/sqrt(k+{beta:g})" in text
    code, text, err = run_cli("run", *args, "--beta", 1000, "--no-progress", "--out", tmp_path / "b")
    assert code == 0 and "steps from the problem" not in text and "/sqrt(k+1000)" in text


@pytest.mark.parametrize("name", ["td0", "tdc", "tdrc"])
def test_the_mean_dynamics_of_an_envs_kept_transitions_estimate_the_models(name):
    """The mean map J(alpha, 0) of the reference's 20 000 kept transitions of the test chain against the map of the
    chain's model: within 5 % of the model's step (|J - I|); measured 0.4-1.5 %, a sampling error of order
    1 / sqrt(20 000) times the features' spread (seeded: the reference's streams are fixed)."""
    from dgtd.algorithms import make_algorithm
    from dgtd.algorithms import mean_dynamics as md
    from dgtd.config import scenario_of

    spec = {"make": env("make_chain"), "features": "one-hot", "agents": 4}
    reference = scenario_of(unflat(dict(env=spec, gamma=chain.GAMMA))).problem
    assert len(reference.sums.kept_transitions()[0]) == 20_000
    model = exact.Moments(make_problem(chain.P, chain.R, np.eye(4), chain.GAMMA))
    algorithm = make_algorithm(name)
    estimated, exactly = (
        md.MeanMap(algorithm, md.transitions(reference.moments))(0.5, 0.0),
        md.MeanMap(algorithm, md.transitions(model))(0.5, 0.0),
    )
    assert np.abs(estimated - exactly).max() <= 0.05 * np.abs(exactly - np.eye(len(exactly))).max()


def test_compare_on_an_env_takes_every_methods_first_step_from_its_estimated_mean_dynamics(run_cli, tmp_path):
    """`dgtd compare --env` as `dgtd compare --problem`: every method's schedule printed, DGTD at the offset `dgtd run
    --env` takes (3 230 on the test chain), the others' from their own mean dynamics, and the rule said."""
    args = ("--env", env("make_chain"), "--features", "one-hot", "--agents", 4, "-T", 200, "--seeds", 1)
    code, text, err = run_cli("compare", *args, "-a", "dgtd,td0,tdc", "--no-plots", "--no-progress", "--out", tmp_path)
    assert code == 0, err
    assert "alpha_k: dgtd 7.906/sqrt(k+3230), td0 1/sqrt(k+1000), tdc 3/sqrt(k+1000)" in text
    assert "every first step at most what the method's mean dynamics allow" in text


def test_a_users_sys_exit_is_an_error_naming_the_function_not_a_silent_exit(run_cli, tmp_path):
    """A features function that calls sys.exit(0) made dgtd exit 0 with no output and no results."""
    user = tmp_path / "quits.py"
    user.write_text("import sys\n\ndef features(states):\n    sys.exit(0)\n")
    out = tmp_path / "out"
    code, _, err = run_cli(
        "run",
        "--env",
        env("make_chain"),
        "--features",
        f"{user}:features",
        "--gamma",
        0.8,
        "-T",
        100,
        "--no-plots",
        "--no-progress",
        "--out",
        out,
    )
    assert code == 2 and "sys.exit(0)" in err and "features" in err and len(err.strip().splitlines()) == 1
    assert not (out / "summary.json").exists()
