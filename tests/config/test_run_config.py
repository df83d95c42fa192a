"""One run configuration: the sectioned experiment file, the older flat one, the Python API and the command line
all describe the same `RunConfig` and give the same run."""

from __future__ import annotations

import tomllib

import pytest

import dgtd
from dgtd.config import AlgorithmConfig, NetworkConfig, ProblemConfig, RunConfig, RunLength, SamplingConfig
from dgtd.errors import DgtdInputError
from dgtd.experiments import parse, to_toml

SECTIONED = """
[problem]
scenario = "paper-example-1"
reward_noise = "bernoulli"
[network]
edge_prob = 0.6
[algorithm]
name = "dgtd"
alpha0 = 2
box_scale = 3.0
[sampling]
mode = "markov"
[run]
iterations = 1500
seeds = 2
backend = "numpy"
[output]
out = "o"
plots = false
"""

FLAT = """
scenario = "paper-example-1"
reward_noise = "bernoulli"
edge_prob = 0.6
algorithm = "dgtd"
alpha0 = 2
sampling = "markov"
iterations = 1500
seeds = 2
backend = "numpy"
out = "o"
plots = false
[algorithm_params]
box_scale = 3.0
"""

PYTHON = RunConfig(
    ProblemConfig(scenario="paper-example-1", reward_noise="bernoulli"),
    NetworkConfig(edge_prob=0.6),
    AlgorithmConfig("dgtd", {"alpha0": 2.0, "box_scale": 3.0}),
    SamplingConfig(mode="markov"),
    RunLength(iterations=1500, seeds=2, backend="numpy"),
    dgtd.Output(out="o", plots=False),
)


def test_the_sectioned_file_the_flat_file_and_python_are_one_config():
    sectioned, flat = parse(tomllib.loads(SECTIONED)).config, parse(tomllib.loads(FLAT)).config
    assert sectioned == flat == PYTHON
    assert parse(tomllib.loads(to_toml(parse(tomllib.loads(FLAT))))).config == PYTHON  # written sectioned, read back


@pytest.mark.parametrize(
    "text, words",
    [
        ("[network]\nedge_prb = 0.5\n", "unknown field 'edge_prb' in \\[network\\].*did you mean 'edge_prob'"),
        ("[run]\nseeds = 'two'\n", "run.seeds .*must be an integer"),
        ("[algorithm]\nalpha0 = 'ten'\n", "algorithm.alpha0 .*must be a number"),
        ("[problem]\nscenario = 3\n", "problem.scenario .*must be a string"),
        ("[runs]\nseeds = 2\n", "unknown field 'runs'.*did you mean 'run'"),
        ("[output]\ncheckpoint_every = -1\n", "checkpoint_every must be >= 0"),
    ],
)
def test_a_bad_field_in_a_section_is_named(text, words):
    with pytest.raises(DgtdInputError, match=words):
        parse(tomllib.loads(text), "exp.toml")


def test_an_algorithm_field_is_checked_against_that_algorithm():
    from dgtd.config import resolve

    bad = RunConfig(ProblemConfig(scenario="paper-example-1"), algorithm=AlgorithmConfig("td0", {"kappa": 1.0}))
    with pytest.raises(DgtdInputError, match="algorithm 'td0' has no parameter 'kappa'"):
        resolve(bad)
    typo = RunConfig(ProblemConfig(scenario="paper-example-1"), algorithm=AlgorithmConfig("dgtd", {"box_scal": 1.0}))
    with pytest.raises(DgtdInputError, match="did you mean 'box_scale'"):
        resolve(typo)


def test_execute_runs_a_config_as_dgtd_run_does(tmp_path, run_cli, monkeypatch):
    """The Python API's argument and the experiment file give byte-identical metrics."""
    from dataclasses import replace

    monkeypatch.chdir(tmp_path)
    result = dgtd.execute(replace(PYTHON, output=dgtd.Output(out="api", plots=False, progress=False)))
    assert result.metrics["error_last"].shape[1] == 2
    (tmp_path / "exp.toml").write_text(SECTIONED)
    code, _, err = run_cli("run", "exp.toml", "--out", "cli", "--no-progress")
    assert code == 0, err
    assert (tmp_path / "api" / "metrics.csv").read_bytes() == (tmp_path / "cli" / "metrics.csv").read_bytes()
    assert (tmp_path / "api" / "config.toml").read_text().replace("/api", "/cli").replace("progress = false", "") == (
        tmp_path / "cli" / "config.toml"
    ).read_text().replace("progress = false", "")


def test_results_written_before_the_episodic_convention_existed_are_still_this_run(tmp_path, run_cli):
    """A directory whose summary.json predates `restarts` (no such key) holds the same run: rerunning it into its
    own directory needs no --overwrite, as before."""
    import json

    args = ("run", "paper-example-1", "-T", 100, "--no-plots", "--no-progress", "--out", tmp_path / "o")
    code, _, err = run_cli(*args)
    assert code == 0, err
    summary = tmp_path / "o" / "summary.json"
    data = json.loads(summary.read_text())
    for key in ("restarts", "loss", "burst", "reweight"):
        data["config"].pop(key, None)
    summary.write_text(json.dumps(data))
    code, _, err = run_cli(*args)
    assert code == 0, err
