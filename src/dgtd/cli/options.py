"""Command-line options made from the fields of the run's configuration (`dgtd.config.RunConfig`): each field
declares its option with itself (`dgtd.fields.option`: its help, and its spelling where it is not --field-name), and
this module makes them into one table, `RUN_OPTIONS`, by their flat names (`dgtd.config.FLAT`), from which `dgtd run`,
`dgtd sweep`, `dgtd solve` and `dgtd compare` each take theirs, so that an option means the same everywhere. The
options' type is the field's, their choices `dgtd.config.CHOICES`, their default None (the scenario's value, else the
library's default, which the help shows); an algorithm's fields are options too, one per name over the registered
algorithms (`ALGORITHM_OPTIONS`). tests/config/test_config_cli.py checks that every field has its option and every
option its field."""

from __future__ import annotations

import typing
from dataclasses import fields
from pathlib import Path

import click

from dgtd.config import CHOICES, FLAT, SECTIONS, STEP_SIZE_FIELDS, Output, field_types
from dgtd.errors import DgtdInputError
from dgtd.fields import declared, option_of


def _floats(value: str, wanted: str) -> list[float]:
    """'x,y,...' as numbers, or a one-line refusal that says what was ``wanted``."""
    try:
        return [float(x) for x in value.split(",")]
    except ValueError:
        raise click.BadParameter(f"give {wanted}; got {value!r}") from None


def _numbers(ctx, param, value):
    """A list option given as 'x,y,...' (e.g. --boxes 1,2,3,4)."""
    return None if value is None else tuple(_floats(value, "numbers separated by commas, e.g. 1,2.5,3"))


def _split(ctx, param, value):
    """--split: 'random' or shares 'w_1,...,w_N' (a list)."""
    if value is None or value == "random":
        return value
    return _floats(value, "'random' or the agents' shares separated by commas, e.g. 0.5,0.3,0.2")


def declared_option(f) -> dict:
    """The option a field declares (`dgtd.fields.option`): every field handed here has one."""
    spec = option_of(f)
    if spec is None:
        raise TypeError(f"field {f.name} declares no command-line option")
    return spec


CALLBACKS = {"split": _split, "boxes": _numbers}
"""Options whose text is parsed here (a field of a list type); the others are parsed by the config's checks."""


def _kind(name: str, hint, choices=None):
    """The click type of a field's option, from its type: a choice, an int, a float, a switch (bool) or text."""
    choices = choices or CHOICES.get(name)
    if choices:
        return click.Choice(choices)
    kinds = [t for t in typing.get_args(hint) or (hint,) if t is not type(None)]
    if len(kinds) == 1 and kinds[0] in (int, float, bool):
        return kinds[0]
    return str  # text the config parses: a name, a file, a probability or a list of them


def make_option(name: str, f, hint, help: str, default=None, show_default: bool = False, choices=None):
    """The click option of field ``f`` (type ``hint``) under the flat ``name``; ``choices``: its valid values, where
    they are not the run's (`CHOICES`)."""
    spec = declared_option(f)
    kind = _kind(name, hint, choices)
    dashed = "--" + name.replace("_", "-")
    if kind is bool:
        flags = spec["flags"] or (f"{dashed}/--no-{name.replace('_', '-')}",)
        return click.option(*flags, name, default=default, show_default=show_default, help=help)
    return click.option(
        *(spec["flags"] or (dashed,)),
        name,
        type=kind,
        default=default,
        show_default=show_default,
        metavar=spec["metavar"],
        callback=CALLBACKS.get(name),
        help=help,
    )


def shown(name: str) -> str:
    """The default an option of the run's length (`dgtd.config.RunLength`) stands for. The option's own default is
    None, the config's ('not given': an experiment file's value stays); `dgtd.run.loop.RunSettings`' applies."""
    from dgtd.run.loop import RunSettings

    return f"  [default: {getattr(RunSettings, name)}]"


def _config_options() -> dict:
    """{flat name: option} of every config field that has one, section by section."""
    names = {place: name for name, place in FLAT.items()}
    out = {}
    for section, cls in SECTIONS.items():
        if section == "output":
            continue
        hints = field_types(cls)
        for f in fields(cls):
            spec = option_of(f)
            if spec is None:
                continue
            name = names[section, f.name]
            help = spec["help"]
            if section == "run" and "default" not in help.lower():
                help += shown(f.name)
            out[name] = make_option(name, f, hints[f.name], help)
        if section == "problem":
            out.update(_env_options())
    return out


def _env_options() -> dict:
    """The fields of a user's simulator (`dgtd.scenarios.user.EnvSpec`, the [env] table): --env (its make),
    --features, --policy, ...; their defaults are EnvSpec's, which the help says."""
    from dgtd.experiments import env_flag
    from dgtd.scenarios.user import EnvSpec

    hints, out = field_types(EnvSpec), {}
    for f in fields(EnvSpec):
        if option_of(f) is not None:
            name = env_flag(f.name)
            out[name] = make_option(name, f, hints[f.name], declared_option(f)["help"])
    return out


def _value(x) -> str:
    return f"{x:g}" if isinstance(x, float) else "none" if x is None else str(x)


def _algorithm_options() -> dict:
    """One option per field name of the registered algorithms (--alpha0, --kappa, --eta, ...): its help the field's
    (each meaning, with the algorithms that have it, where they differ), then the algorithms' defaults."""
    from dgtd.algorithms import ALGORITHMS

    by_name: dict = {}
    for algorithm, cls in ALGORITHMS.items():
        for f in fields(cls):
            if declared(cls, f.name) is not None:
                by_name.setdefault(f.name, []).append((algorithm, cls, f))
    out = {}
    for name, owners in by_name.items():
        meanings: dict = {}
        defaults: dict = {}
        for algorithm, cls, f in owners:
            meanings.setdefault(declared_option(declared(cls, name))["help"], []).append(algorithm)
            defaults.setdefault(_value(f.default), []).append(algorithm)
        everyone = len(owners) == len(ALGORITHMS)
        if len(meanings) == 1:
            (help,) = meanings
            help += "" if everyone else f" Algorithms: {', '.join(algorithm for algorithm, _, _ in owners)}."
        else:
            help = " ".join(f"{', '.join(who)}: {text}" for text, who in meanings.items())
        common = max(defaults, key=lambda v: len(defaults[v]))
        rest = "; ".join(f"{', '.join(who)} {v}" for v, who in defaults.items() if v != common)
        others = "" if not rest else ("the others " if everyone else f"{', '.join(defaults[common])} ")
        if name in STEP_SIZE_FIELDS:  # another method takes the scenario's steps (`dgtd.config.build_algorithm`)
            dgtd = _value(getattr(ALGORITHMS["dgtd"](), name))
            help += (
                f" Default: the scenario's, whatever --algorithm (a problem file's: DGTD's {dgtd}; a simulator's or "
                "a recording's: scaled to its features); with no step option on a user's problem the first step "
                "comes from the problem. dgtd compare gives each method its own and prints the options that repeat "
                "its rows."
            )
        else:
            help += f" Default: the scenario's, else {rest + '; ' if rest else ''}{others}{common}."
        cls = owners[0][1]
        out[name] = make_option(name, declared(cls, name), field_types(cls)[name], help)
    return out


def output_options(*names: str, helps: dict | None = None):
    """Decorate a command with `Output`'s fields that are options (--out, --plots, ...; those of ``names``, or every
    one), its defaults shown; ``helps``: another command's words for what a field means to it."""
    hints, helps = field_types(Output), helps or {}
    return _all(
        make_option(
            f.name, f, hints[f.name], helps.get(f.name, declared_option(f)["help"]), f.default, f.default is not None
        )
        for f in fields(Output)
        if option_of(f) is not None and (not names or f.name in names)
    )


def sweep_options():
    """Decorate `dgtd sweep` with the fields of `dgtd.experiments.SweepOptions` (--executor, --workers, ...), its
    defaults shown, choices `dgtd.experiments.EXECUTORS` and `TABLE_FORMATS`."""
    from dgtd.experiments import EXECUTORS, TABLE_FORMATS, SweepOptions

    hints, choices = field_types(SweepOptions), {"executor": EXECUTORS, "format": TABLE_FORMATS}
    return _all(
        make_option(
            f.name, f, hints[f.name], declared_option(f)["help"], f.default, f.default is not None, choices.get(f.name)
        )
        for f in fields(SweepOptions)
    )


def run_options(*names: str):
    """Decorate a command with the options of ``names`` from `RUN_OPTIONS` (all of them when none are named), in
    the table's order."""
    return _all(option for name, option in RUN_OPTIONS.items() if not names or name in names)


def _all(options):
    """One decorator of ``options``, in their order on the command's help."""
    chosen = list(options)

    def decorate(command):
        for option in reversed(chosen):
            command = option(command)
        return command

    return decorate


def _options() -> dict:
    config = _config_options()
    at = list(config).index("algorithm") + 1  # an algorithm's fields after its name
    items = list(config.items())
    return dict(items[:at] + list(ALGORITHM_OPTIONS.items()) + items[at:])


ALGORITHM_OPTIONS = _algorithm_options()
"""Field name -> its option, over the registered algorithms' fields (a run sets those of the algorithm it runs)."""
RUN_OPTIONS = _options()
"""Flat field name (or [env] flag) -> its option: every run option, made from its field."""
LINK_OPTIONS = tuple(f.name for f in fields(SECTIONS["network"]) if f.name not in ("graph", "edge_prob"))
"""The links' options (`dgtd.config.NetworkConfig`), which run, sweep, solve and compare all take."""
ENV_OPTIONS = (*_env_options(), "data", "gamma")
"""The options of a user's simulator or recordings (--env, --features, ..., --data, --gamma)."""


def problem_line(problem, links: str) -> str:
    """What a run is on, in one line: the problem (a model's states, or an estimated reference) and its network."""
    from dgtd.problems.model import Problem

    states = f"{problem.n_states} states" if isinstance(problem, Problem) else "no model (an estimated reference)"
    return (
        f"{problem.name}: {states}, {problem.n_agents} agents, {problem.n_features} features, gamma "
        f"{problem.gamma:g}{', off-policy' if problem.off_policy else ''}; network: {links}"
    )


def given_flags(ctx: click.Context, exclude=()) -> dict:
    """The options typed on the command line (not defaults): they override an experiment file's fields."""
    from click.core import ParameterSource

    return {
        name: value
        for name, value in ctx.params.items()
        if name not in exclude
        and ctx.get_parameter_source(name) in (ParameterSource.COMMANDLINE, ParameterSource.ENVIRONMENT)
    }


def resume_folder(resume_dir, out, what: str, start: str) -> Path:
    """The folder ``--resume DIR`` continues (``what``: "run" or "learning run"), checked: an --out elsewhere, or a
    folder that is not one or holds no config.toml, is one line saying how to start one there (``start``, the
    command with its --out and --checkpoint-every to come)."""
    folder = Path(resume_dir)
    if out is not None and Path(out).resolve() != folder.resolve():
        raise DgtdInputError(
            f"--resume continues the {what} in {folder} and writes there; leave out --out {out} (or resume that "
            "directory instead)"
        )
    if not (folder / "config.toml").is_file():
        held = "is not a directory" if not folder.is_dir() else f"holds no {what} (no config.toml)"
        raise DgtdInputError(
            f"--resume {folder}: {held}; start a {what} there with `{start} --out {folder} --checkpoint-every K`, "
            "then resume it"
        )
    return folder
