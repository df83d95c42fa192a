"""Experiment files: parsing, command-line overrides, resolved config.toml that reproduces a run, bad input."""

from __future__ import annotations

import json
import tomllib
from dataclasses import replace

import pytest

from dgtd.config import Output, resolve, unflat, view
from dgtd.errors import DgtdInputError
from dgtd.experiments import Experiment, load, override, parse, to_toml

SMALL = 'scenario = "paper-example-1"\niterations = 3000\nseeds = 2\ncheckpoints = 10\nbackend = "numpy"\n'


def write(tmp_path, text, name="exp.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_fields_go_to_spec_output_grid_and_sweep():
    exp = parse(
        {
            "scenario": "paper-example-1",
            "alpha0": 2,
            "out": "x",
            "checkpoint_every": 5,
            "params": {},
            "algorithm_params": {"box_scale": 3},
            "grid": {"kappa": [0, 1], "params": {"n": [1, 2]}},
            "sweep": {"executor": "ray", "workers": 4},
        }
    )
    assert view(exp.config).alpha0 == 2.0 and isinstance(
        view(exp.config).alpha0, float
    )  # an integer is accepted for a float
    assert view(exp.config).algorithm_params == {"box_scale": 3}
    assert exp.config.output == Output(out="x", checkpoint_every=5)
    assert exp.grid == {"kappa": [0.0, 1.0], "params": {"n": [1, 2]}}
    assert exp.sweep.executor == "ray" and exp.sweep.workers == 4


def test_toml_round_trip_is_exact(tmp_path):
    spec = unflat(
        dict(
            scenario="paper-example-1",
            alpha0=0.1 + 0.2,
            iterations=123,
            params=None,
            algorithm_params={"box_scale": 2.5},
        )
    )
    exp = Experiment(replace(spec, output=Output(out="o", plots=False)), grid={"kappa": [0.0, 1.5]})
    path = write(tmp_path, to_toml(exp, "a comment"))
    back = load(path)
    assert back == exp
    assert view(back.config).alpha0 == 0.1 + 0.2  # floats survive to the last bit


def test_flags_override_the_file(tmp_path):
    exp = load(write(tmp_path, SMALL + "kappa = 0.5\n"))
    exp = override(exp, {"kappa": 2.0, "out": "elsewhere", "sweep.resume": False})
    assert view(exp.config).kappa == 2.0 and view(exp.config).iterations == 3000
    assert exp.config.output.out == "elsewhere" and exp.sweep.resume is False


@pytest.mark.parametrize(
    "text, message",
    [
        ('scenario = "paper-example-1"\nkapa = 1.0\n', "unknown field 'kapa' in .*did you mean 'kappa'"),
        ('scenario = "paper-example-1"\nalpha0 = "big"\n', "field 'alpha0' .* must be a number, got 'big'"),
        ('scenario = "paper-example-1"\nseeds = 2.5\n', "field 'seeds' .* must be an integer"),
        ('scenario = "paper-example-1"\nshared = 1\n', "field 'shared' .* must be true or false"),
        (
            'scenario = "paper-example-1"\n[grid]\nkapa = [1.0]\n',
            r"unknown field 'kapa' in \[grid\].*did you mean 'kappa'",
        ),
        ('scenario = "paper-example-1"\n[grid]\nkappa = 1.0\n', "grid.kappa .* must be a non-empty list"),
        (
            'scenario = "paper-example-1"\n[sweep]\nexecuter = "ray"\n',
            "unknown field 'executer'.*did you mean 'executor'",
        ),
        ('scenario = "paper-example-1"\n[sweep]\nexecutor = "dask"\n', "executor must be one of process, ray"),
        ('scenario = "paper-example-1\n', "is not valid TOML"),
    ],
)
def test_bad_files_name_the_field(tmp_path, text, message):
    with pytest.raises(DgtdInputError, match=message):
        load(write(tmp_path, text))


@pytest.mark.parametrize(
    "spec, message",
    [
        (unflat(dict(scenario="paper-exmple-1")), "unknown scenario 'paper-exmple-1'.*did you mean 'paper-example-1'"),
        (unflat(dict(scenario="paper-example-1", algorithm="dgdt")), "unknown algorithm 'dgdt'; did you mean 'dgtd'"),
        (
            unflat(dict(scenario="paper-example-1", params={"size": 3})),
            "scenario 'paper-example-1' has no parameter 'size'",
        ),
        (
            unflat(dict(scenario="paper-example-1", algorithm_params={"box_scal": 3.0})),
            "no parameter 'box_scal'; did you mean 'box_scale'",
        ),
        (unflat(dict(scenario="paper-example-1", algorithm_params={"box_scale": "x"})), "box_scale must be a number"),
    ],
)
def test_bad_specs_fail_with_a_useful_message(spec, message):
    with pytest.raises(DgtdInputError, match=message):
        resolve(spec)


def test_resolved_spec_records_everything():
    resolved = resolve(unflat(dict(scenario="paper-example-1", iterations=10))).config
    assert resolved.algorithm.name == "dgtd" and resolved.network.edge_prob == 0.8  # the scenario's, written down
    assert resolved.algorithm.fields == {
        "alpha0": 10.0,
        "beta": 100.0,
        "schedule": "sqrt",
        "kappa": 1.0,
        "rho": 0.0,
        "box_scale": 2.0,
    }
    # resolving a resolved spec changes nothing: a saved config means the same run later
    assert resolve(resolved).config == resolved


@pytest.mark.parametrize(
    "args, message",
    [
        (("run", "{dir}/exp.toml"), "unknown field 'kapa'"),
        (("run", "paper-exmple-1"), "unknown scenario 'paper-exmple-1'"),
        (("run", "{dir}/grid.toml"), "has a \\[grid\\]: run it with `dgtd sweep FILE`"),
        (("sweep", "{dir}/exp.toml"), "unknown field 'kapa'"),
        (("run", "{dir}/missing.toml"), "does not exist"),
    ],
)
def test_cli_exits_2_with_one_line(tmp_path, run_cli, args, message):
    import re

    write(tmp_path, 'scenario = "paper-example-1"\nkapa = 1.0\n')
    write(tmp_path, SMALL + "[grid]\nkappa = [0.0]\n", "grid.toml")
    code, out, err = run_cli(*(a.format(dir=tmp_path) for a in args))
    assert code == 2
    assert err.startswith("dgtd: error:") and err.count("\n") == 1 and re.search(message, err), err


def test_config_toml_reproduces_the_run(tmp_path, run_cli):
    exp = write(tmp_path, SMALL + 'reward_noise = "bernoulli"\nedge_prob = 0.6\nplots = false\nprogress = false\n')
    code, out, err = run_cli("run", exp, "--out", tmp_path / "a", "--kappa", "0.5")
    assert code == 0, err
    saved = tomllib.loads((tmp_path / "a" / "config.toml").read_text())
    assert saved["algorithm"]["kappa"] == 0.5 and saved["network"]["edge_prob"] == 0.6
    assert saved["problem"]["reward_noise"] == "bernoulli" and saved["output"]["out"] == str(tmp_path / "a")
    code, out, err = run_cli("run", tmp_path / "a" / "config.toml", "--out", tmp_path / "b")
    assert code == 0, err
    assert (tmp_path / "a" / "metrics.csv").read_bytes() == (tmp_path / "b" / "metrics.csv").read_bytes()
    sa, sb = (json.loads((tmp_path / d / "summary.json").read_text()) for d in "ab")
    sa.pop("seconds"), sb.pop("seconds")
    assert sa == sb
    # and the flags alone give the same run as the file
    code, out, err = run_cli(
        "run",
        "paper-example-1",
        "-T",
        "3000",
        "--seeds",
        "2",
        "--checkpoints",
        "10",
        "--backend",
        "numpy",
        "--reward-noise",
        "bernoulli",
        "--edge-prob",
        "0.6",
        "--kappa",
        "0.5",
        "--no-plots",
        "--no-progress",
        "--out",
        tmp_path / "c",
    )
    assert code == 0, err
    assert (tmp_path / "a" / "metrics.csv").read_bytes() == (tmp_path / "c" / "metrics.csv").read_bytes()


def test_every_command_line_option_is_a_field():
    """So that an experiment file can say anything the command line can (the --env flags: fields of its [env] table)."""
    from dgtd.cli import cli
    from dgtd.config import FLAT, algorithm_fields, field_types
    from dgtd.experiments import ENV_FLAGS, SCENARIO_FLAGS, SWEEP_TYPES
    from dgtd.scenarios.user import EnvSpec

    env_fields = field_types(EnvSpec)
    assert all(field in env_fields for field in (*ENV_FLAGS.values(), *SCENARIO_FLAGS))

    renamed = {"resume_dir": "resume"}
    LAUNCH = ("ranks", "hosts")  # how the run's processes start (mpiexec's -n and -f), not the run: no fields
    for command, positional in (("run", "scenario"), ("sweep", "experiment")):
        options = [p.name for p in cli.commands[command].params if p.name != positional]
        assert options
        for name in options:
            name = renamed.get(name, name)
            if name in ENV_FLAGS or name in SCENARIO_FLAGS or name in LAUNCH:
                continue
            # an algorithm's field without a flat name of its own: its [algorithm] table's (algorithm_params)
            assert name in FLAT or name in SWEEP_TYPES or name in algorithm_fields(), f"dgtd {command} --{name}"


def test_problem_files_are_recorded_with_absolute_paths(tmp_path, monkeypatch, run_cli):
    from dgtd.problems.io import save_problem
    from dgtd.scenarios import get_scenario

    monkeypatch.chdir(tmp_path)
    save_problem("chain.npz", get_scenario("paper-example-1").problem)
    (tmp_path / "edges.txt").write_text("0 1\n1 2\n2 3\n3 4\n")
    write(
        tmp_path,
        'problem_file = "chain.npz"\ngraph = "edges.txt"\niterations = 500\nbackend = "numpy"\n'
        'plots = false\nprogress = false\nout = "o"\n',
    )
    code, out, err = run_cli("run", "exp.toml")
    assert code == 0, err
    saved = tomllib.loads((tmp_path / "o" / "config.toml").read_text())
    assert saved["problem"]["problem_file"] == str(tmp_path / "chain.npz")
    assert saved["network"]["graph"] == str(tmp_path / "edges.txt")
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert len(summary["config"]["problem_sha256"]) == 64
    write(tmp_path, 'problem_file = "chain.npz"\n[params]\nsize = 3\n', "bad.toml")
    code, _, err = run_cli("run", "bad.toml")
    assert code == 2 and "params are a scenario's parameters" in err
