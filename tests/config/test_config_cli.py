"""The command line has no defaults or choice lists of its own: every option of `dgtd run`, `dgtd sweep` and
`dgtd compare` that names a field of the run configuration takes that field's default and valid values."""

from __future__ import annotations

import dataclasses

import click
import pytest

from dgtd.algorithms import ALGORITHMS
from dgtd.cli import cli
from dgtd.config import CHOICES, RunSpec
from dgtd.experiments import EXECUTORS, TABLE_FORMATS, Output, SweepOptions
from dgtd.run.loop import RunSettings


def defaults(*classes) -> dict:
    return {f.name: f.default for cls in classes for f in dataclasses.fields(cls)}


FIELDS = defaults(RunSpec, Output)
COMMAND_FIELDS = {"run": FIELDS, "sweep": defaults(RunSpec, Output, SweepOptions)}  # a sweep's own resume wins


def options(command: str) -> dict:
    return {p.name: p for p in cli.commands[command].params if isinstance(p, click.Option)}


@pytest.mark.parametrize("command", ["run", "sweep"])
def test_run_options_take_the_configuration_defaults_and_choices(command):
    opts = options(command)
    checked = 0
    for name, option in opts.items():
        fields = COMMAND_FIELDS[command]
        if name in fields and name != "out":
            assert option.default == fields[name], name
            checked += 1
        if isinstance(option.type, click.Choice):
            valid = CHOICES.get(name) or {"executor": EXECUTORS, "format": TABLE_FORMATS}[name]
            assert tuple(option.type.choices) == tuple(valid), name
    assert checked >= 8


def test_the_run_configuration_defaults_are_the_run_settings():
    for name in ("seeds", "seed", "checkpoints", "tail_fraction", "block_size", "backend"):
        assert FIELDS[name] == getattr(RunSettings(), name)
    sweep = options("sweep")
    assert sweep["executor"].default == SweepOptions.executor and sweep["format"].default == SweepOptions.format


def test_compare_options_take_the_run_settings_defaults_and_the_algorithm_names():
    opts = options("compare")
    assert opts["checkpoints"].default == RunSettings.checkpoints
    assert opts["backend"].default == RunSettings.backend
    assert tuple(opts["backend"].type.choices) == CHOICES["backend"]
    assert all(name in opts["algorithms"].help for name in ALGORITHMS)
