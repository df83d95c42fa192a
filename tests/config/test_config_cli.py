"""The command line has no defaults or choice lists of its own: every option of `dgtd run`, `dgtd sweep` and
`dgtd compare` that names a field of the run configuration takes that field's default and valid values."""

from __future__ import annotations

import dataclasses

import click
import pytest

from dgtd.algorithms import ALGORITHMS
from dgtd.cli import cli
from dgtd.config import CHOICES, FLAT, SECTIONS, RunConfig, flat
from dgtd.experiments import EXECUTORS, TABLE_FORMATS, SweepOptions
from dgtd.run.loop import RunSettings


def config_default(name: str):
    """The default of the config field of flat name ``name``."""
    section, key = FLAT[name]
    if section == "algorithm" and key != "name":
        return None  # an algorithm's field left out: the scenario's
    return getattr(getattr(RunConfig(), section), key)


SWEEP_DEFAULTS = {f.name: f.default for f in dataclasses.fields(SweepOptions)}


def options(command: str) -> dict:
    return {p.name: p for p in cli.commands[command].params if isinstance(p, click.Option)}


@pytest.mark.parametrize("command", ["run", "sweep"])
def test_run_options_are_the_configuration_s_fields_with_its_defaults_and_choices(command):
    opts = options(command)
    checked = 0
    for name, option in opts.items():
        if command == "sweep" and name in SWEEP_DEFAULTS:  # a sweep's own resume wins
            assert option.default == SWEEP_DEFAULTS[name], name
        elif name in FLAT and name != "out":
            assert option.default == config_default(name), name
            checked += 1
        if isinstance(option.type, click.Choice):
            valid = CHOICES.get(name) or {"executor": EXECUTORS, "format": TABLE_FORMATS}[name]
            assert tuple(option.type.choices) == tuple(valid), name
    assert checked >= 20


def test_the_run_length_options_show_the_run_settings_defaults_that_apply():
    """--seeds and the like leave the config's None (an experiment file's value stays) and say RunSettings' default."""
    opts = options("run")
    for name in ("seeds", "seed", "checkpoints", "tail_fraction", "block_size", "backend"):
        assert FLAT[name] == ("run", name)
        assert opts[name].default is None and f"[default: {getattr(RunSettings, name)}]" in opts[name].help
    sweep = options("sweep")
    assert sweep["executor"].default == SweepOptions.executor and sweep["format"].default == SweepOptions.format


def test_every_section_field_has_one_flat_name_and_they_round_trip():
    located = [loc for loc in FLAT.values()]
    assert len(set(located)) == len(located)
    for section, cls in SECTIONS.items():
        for f in dataclasses.fields(cls):
            if section == "algorithm" and f.name == "fields":
                continue
            assert (section, f.name) in located, (section, f.name)
    from dgtd.config import unflat

    values = {name: f"v-{name}" for name in flat(RunConfig())} | {"env": {"make": "m:f"}, "params": {"a": 1}}
    values["algorithm_params"] = {"box_scale": 2.0}
    assert flat(unflat(values)) == values


def test_every_command_takes_its_run_options_from_the_one_table():
    """An option that sets a run field is the same option in run, sweep, solve and compare (help, type, default)."""
    from dgtd.cli.options import RUN_OPTIONS

    run = options("run")
    shared = 0
    for command in ("sweep", "solve", "compare"):
        for name, option in options(command).items():
            if name in RUN_OPTIONS and not (command == "compare" and name == "seeds"):  # compare's own: 5 seeds
                assert (option.help, option.default, str(option.type)) == (
                    run[name].help,
                    run[name].default,
                    str(run[name].type),
                ), f"dgtd {command} --{name}"
                shared += 1
    assert shared >= 40
    compare = options("compare")
    assert {"iterations", "seed", "backend", "checkpoints", "restarts", "problem_file", "env_make"} <= set(compare)
    assert all(name in compare["algorithms"].help for name in ALGORITHMS)


NOT_OPTIONS = {
    ("problem", "scenario"): "the commands' argument SCENARIO",
    ("problem", "params"): "a scenario's keyword arguments: a table of an experiment file",
    ("problem", "env"): "the [env] table: each of its fields is an option (test below)",
    ("algorithm", "fields"): "each registered algorithm's field is an option (test below)",
    ("output", "resume"): "--resume DIR sets it with the directory",
}
COMMAND_ONLY = {"resume_dir", "ranks", "hosts"}  # `dgtd run`'s own: --resume DIR, --ranks R, --hosts FILE


def test_every_config_field_has_its_option_and_every_option_its_field():
    """The options are made from the fields (`dgtd.fields.option`): none is missing, none is extra."""
    from dgtd.config import algorithm_fields
    from dgtd.scenarios.user import EnvSpec

    run = options("run")
    names = {place: name for name, place in FLAT.items()}
    expected = set()
    for section, cls in SECTIONS.items():
        for f in dataclasses.fields(cls):
            if (section, f.name) not in NOT_OPTIONS:
                expected.add(f.name if section == "output" else names[section, f.name])
    expected |= {"env_make" if f.name == "make" else f.name for f in dataclasses.fields(EnvSpec) if f.name != "args"}
    expected |= {f.name for cls in ALGORITHMS.values() for f in dataclasses.fields(cls)}
    assert set(algorithm_fields()) >= {"alpha0", "kappa", "eta", "timescale", "box_scale", "boxes"}
    assert expected - set(run) == set(), "fields without their option"
    assert set(run) - expected == COMMAND_ONLY, "options without their field"


def _main(capsys, *args) -> tuple[int, str]:
    from dgtd.cli import main

    try:
        main([str(a) for a in args])
        code = 0
    except SystemExit as e:
        code = e.code
    out, err = capsys.readouterr()
    return code, out + err


def test_an_algorithms_own_field_on_the_command_line_reaches_its_config(capsys, tmp_path):
    """--eta, --timescale, --box-scale and --boxes (fields without a flat name) set the algorithm's fields."""
    import json

    args = ["run", "paper-example-1", "-T", "200", "--backend", "numpy", "--no-plots", "--no-progress"]
    code, text = _main(
        capsys, *args, "--algorithm", "gtd2", "--eta", "0.5", "--timescale", "0.8", "--out", tmp_path / "a"
    )
    assert code == 0, text
    spec = json.loads((tmp_path / "a" / "summary.json").read_text())["config"]
    assert spec["algorithm_params"] == {"eta": 0.5, "timescale": 0.8}
    code, text = _main(capsys, *args, "--boxes", "100,20,20,100", "--box-scale", "3", "--out", tmp_path / "b")
    assert code == 0, text
    spec = json.loads((tmp_path / "b" / "summary.json").read_text())["config"]
    assert spec["algorithm_params"] == {"box_scale": 3.0, "boxes": [100.0, 20.0, 20.0, 100.0]}
    code, text = _main(capsys, *args, "--algorithm", "td0", "--eta", "0.5", "--out", tmp_path / "c")
    assert code == 2 and "has no parameter 'eta'" in text, text
    code, text = _main(capsys, *args, "--boxes", "1,x", "--out", tmp_path / "d")
    assert code == 2 and "numbers separated by commas" in text, text


def test_an_env_field_on_the_command_line_sets_the_env_table():
    from dgtd.experiments import Experiment, override

    exp = override(Experiment(RunConfig()), {"env_make": "m:f", "radius": 2.5, "positions": "m:pos", "pilot_steps": 9})
    assert exp.config.problem.env == {"make": "m:f", "radius": 2.5, "positions": "m:pos", "pilot_steps": 9}
