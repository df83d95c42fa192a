"""Experiment files: a run or a sweep written down once as TOML, and read back exactly.

An experiment file is a `dgtd.config.RunConfig`, one table per section, and for ``dgtd sweep`` a ``[grid]`` table
and a ``[sweep]`` table::

    [problem]                           # exactly one of scenario, problem_file, data or an [problem.env] table
    scenario = "paper-example-1"
    [network]
    edge_prob = 0.5                     # and the links: loss, burst, delay, wake, bits, ... (docs/links.md)
    [algorithm]                         # its name, and any field of its config
    name = "dgtd"
    alpha0 = 10.0
    box_scale = 2.0
    [run]
    iterations = 20000
    seeds = 4
    [output]                            # out, progress, plots, checkpoint_every, resume, overwrite
    out = "runs/example"

    [problem.env]                       # a user's simulator: dgtd.scenarios.user.EnvSpec's fields
    make = "mypackage.envs:make_env"    # (with gamma = 0.9 in [problem], as for data)
    features = "fourier:3"

    [grid]                              # dgtd sweep: the runs are the product of these lists, keyed by the
    alpha0 = [1.0, 10.0]                # fields' flat names (the command line's options, `dgtd.config.FLAT`)
    edge_prob = [0.5, 0.8]
    [grid.env]                          # (also grid.params, grid.algorithm_params)
    features = ["fourier:2", "fourier:3"]

    [sweep]                             # dgtd sweep: executor = "process" or "ray", address, workers, ...
    executor = "process"

Every command-line option of ``dgtd run`` and ``dgtd sweep`` is a field (its flat name: dashes become underscores)
and a flag given on the command line overrides the file. The older flat layout, every field at the top level by its
flat name (``scenario = ...``, ``alpha0 = ...``, ``[params]``, ``[algorithm_params]``), is still read. Relative
paths are taken from the current directory, as on the command line; a resolved config records them as absolute
paths. A field that is not known, or has the wrong type, is an error naming it and the closest known field.
"""

from __future__ import annotations

import tomllib
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from dgtd.algorithms.dgtd import DGTD
from dgtd.config import (
    FLAT,
    SECTIONS,
    RunConfig,
    algorithm_fields,
    check_type,
    closest,
    field_types,
    flat,
    unflat,
    with_flat,
)
from dgtd.errors import DgtdInputError
from dgtd.fields import option, option_of
from dgtd.files import text_of
from dgtd.graphs.chunked import NAMES
from dgtd.graphs.topologies import TOPOLOGIES
from dgtd.scenarios.user import EnvSpec

EXECUTORS = ("process", "ray")
TABLE_FORMATS = ("auto", "parquet", "csv")


@dataclass(frozen=True)
class SweepOptions:
    """How ``dgtd sweep`` hands out its jobs (none of these changes the numbers).

    - ``executor``: 'process' (a pool of local processes) or 'ray'.
    - ``address``: a running Ray cluster (e.g. 'ray://head:10001' or 'auto'); default: start a local one.
    - ``workers``: jobs at once (default: the local cores; on a Ray cluster, its CPUs).
    - ``resume``: skip jobs already finished in ``out`` (default: on when the directory exists).
    - ``format``: the sweep's table, 'parquet' (needs pyarrow), 'csv', or 'auto' (parquet when possible).
    """

    executor: str = field(
        default="process", metadata=option("A pool of local processes, or Ray (pip install 'dgtd[ray]').")
    )
    address: str | None = field(
        default=None,
        metadata=option("Ray cluster to use (e.g. ray://HEAD:10001, or auto); default: a local Ray on 127.0.0.1."),
    )
    workers: int | None = field(
        default=None, metadata=option("Jobs at once (default: the local cores / the local Ray's CPUs).")
    )
    resume: bool | None = field(
        default=None, metadata=option("Skip jobs already finished in OUT (default: on when OUT exists).")
    )
    format: str = field(
        default="auto", metadata=option("The table: Parquet (needs pyarrow), CSV, or Parquet when pyarrow is there.")
    )


@dataclass(frozen=True)
class Experiment:
    """A run's config, and for a sweep its grid ({flat field name: [values]}, with nested tables for ``params``,
    ``algorithm_params`` and ``env``) and executor options."""

    config: RunConfig = RunConfig()
    grid: dict = field(default_factory=dict)
    sweep: SweepOptions = SweepOptions()


SWEEP_TYPES = field_types(SweepOptions)
TABLES = ("params", "algorithm_params", "env")
SECTION_TYPES = {name: field_types(cls) for name, cls in SECTIONS.items()}


def flat_type(name: str):
    """The type of the field of flat name ``name`` (alpha0 ... rho: DGTD's, which has all five; an algorithm's other
    fields are checked against its class by `dgtd.config.resolve`)."""
    section, key = FLAT[name]
    if section == "algorithm" and key != "name":
        return dict | None if key == "params" else field_types(DGTD)[key] | None
    return SECTION_TYPES[section][key]


def _unknown(key: str, valid, where: str) -> DgtdInputError:
    return DgtdInputError(f"unknown field {key!r} in {where}{closest(key, valid)}")


def _grid(data: dict, where: str) -> dict:
    """Check a [grid] table: flat field names mapped to non-empty lists of values of the field's type."""
    grid: dict[str, Any] = {}
    for key, values in data.items():
        if key in TABLES:
            if not isinstance(values, dict):
                raise DgtdInputError(f"grid.{key} in {where} must be a table of lists, e.g. [grid.{key}]")
            grid[key] = {}
            for sub, vals in values.items():
                if not isinstance(vals, list) or not vals:
                    raise DgtdInputError(f"grid.{key}.{sub} in {where} must be a non-empty list of values")
                grid[key][sub] = list(vals)
            continue
        if key not in FLAT or FLAT[key][0] == "output":
            raise _unknown(key, [k for k in FLAT if FLAT[k][0] != "output"], f"[grid] of {where}")
        if not isinstance(values, list) or not values:
            raise DgtdInputError(f"grid.{key} in {where} must be a non-empty list of values, e.g. {key} = [..]")
        grid[key] = [check_type(f"grid.{key} in {where}: each value", v, flat_type(key)) for v in values]
    return grid


def _section(name: str, table: dict, where: str) -> dict:
    """The flat fields of one section's table ([algorithm]: its name and any field of the algorithm)."""
    out = {}
    for key, value in table.items():
        if name == "algorithm":
            if key == "name":
                out["algorithm"] = check_type(f"algorithm.name in {where}", value, str)
            elif key in FLAT and FLAT[key] == ("algorithm", key):
                out[key] = check_type(f"algorithm.{key} in {where}", value, flat_type(key))
            else:
                out.setdefault("algorithm_params", {})[key] = value
            continue
        types = SECTION_TYPES[name]
        if key not in types:
            raise _unknown(key, types, f"[{name}] of {where}")
        flat_name = next(k for k, loc in FLAT.items() if loc == (name, key))
        out[flat_name] = check_type(f"{name}.{key} in {where}", value, types[key])
    return out


def sweep_fields(table, where: str) -> dict:
    """The fields of a [sweep] table (`SweepOptions`'), each checked: an unknown one or a wrong type is one line."""
    sweep = {}
    for k, v in check_type(f"[sweep] in {where}", table, dict).items():
        if k not in SWEEP_TYPES:
            raise _unknown(k, SWEEP_TYPES, f"[sweep] of {where}")
        sweep[k] = check_type(f"sweep.{k} in {where}", v, SWEEP_TYPES[k])
    return sweep


def parse(data: dict, where: str = "the experiment") -> Experiment:
    """An `Experiment` from the data of a TOML file (or any dict of the same shape): one table per section of
    `RunConfig`, or the older flat layout."""
    values: dict[str, Any] = {}
    sweep: dict[str, Any] = {}
    grid: dict[str, Any] = {}
    for key, value in data.items():
        if key in SECTIONS and isinstance(value, dict):
            values.update(_section(key, value, where))
        elif key in FLAT:
            values[key] = check_type(f"field {key!r} in {where}", value, flat_type(key))
        elif key == "grid":
            grid = _grid(check_type(f"[grid] in {where}", value, dict), where)
        elif key == "sweep":
            sweep = sweep_fields(value, where)
        else:
            raise _unknown(key, [*SECTIONS, *FLAT, "grid", "sweep"], where)
    exp = Experiment(unflat(values), grid, SweepOptions(**sweep))
    check_choices(exp)
    return exp


def check_choices(exp: Experiment) -> None:
    if exp.sweep.executor not in EXECUTORS:
        raise DgtdInputError(f"executor must be one of {', '.join(EXECUTORS)}, got {exp.sweep.executor!r}")
    if exp.sweep.format not in TABLE_FORMATS:
        raise DgtdInputError(f"format must be one of {', '.join(TABLE_FORMATS)}, got {exp.sweep.format!r}")
    if exp.sweep.workers is not None and exp.sweep.workers < 1:
        raise DgtdInputError(f"workers must be >= 1 (leave it out to use every core), got {exp.sweep.workers}")


def load(path: str | Path) -> Experiment:
    """Read an experiment file; a missing file, bad TOML or a bad field is a one-line `DgtdInputError`."""
    path = Path(path)
    if path.is_dir():
        path = path / "config.toml"
    return parse(read_data(path), str(path))


def read_data(path: str | Path) -> dict:
    """The data of a TOML file; a missing file or bad TOML is a one-line `DgtdInputError`."""
    path = Path(path)
    try:
        return tomllib.loads(text_of(path))  # (an editor's byte-order mark is no part of the TOML)
    except FileNotFoundError:
        raise DgtdInputError(f"experiment file {path} does not exist") from None
    except UnicodeDecodeError as e:
        raise DgtdInputError(f"{path} is not UTF-8 text, as TOML is ({e})") from None
    except tomllib.TOMLDecodeError as e:
        raise DgtdInputError(f"{path} is not valid TOML: {e}") from None


def env_flag(field_name: str) -> str:
    """The option's parameter name of a field of the [env] table: its own, but env_make for make (--env)."""
    return "env_make" if field_name == "make" else field_name


SCENARIO_FLAGS = ("agents", "policy")
"""Options that set the [env] field of their name in an env run, else the scenario's parameter (mpe-spread's)."""
ENV_FLAGS = {
    env_flag(f.name): f.name for f in fields(EnvSpec) if option_of(f) is not None and f.name not in SCENARIO_FLAGS
}
"""Command-line options that set a field of the [env] table (--env sets make; --features, --split, ...)."""


def override(exp: Experiment, values: dict) -> Experiment:
    """``exp`` with the given fields replaced (command-line flags, by flat name), or the sweep's options;
    'sweep.NAME' names a sweep option whose name a run option also has (resume). The --env flags (`ENV_FLAGS`) set
    fields of the [env] table, and ``agents`` and ``policy`` set those of an env run, else the scenario's parameters
    of those names."""
    config = exp.config
    run, sweep, own = {}, {}, {}
    env = {ENV_FLAGS[k]: v for k, v in values.items() if k in ENV_FLAGS}
    shared = {k: values[k] for k in SCENARIO_FLAGS if values.get(k) is not None}
    if (env and "make" in env) or config.problem.env is not None:
        run["env"] = {**(config.problem.env or {}), **env, **shared}
    elif env:
        run["env"] = env  # flags of an env run without its env: `resolve` says so
    elif shared:
        run["params"] = {**(config.problem.params or {}), **shared}
    for key, value in values.items():
        if key in ENV_FLAGS or key in SCENARIO_FLAGS:
            continue
        if key.startswith("sweep.") and key[6:] in SWEEP_TYPES:  # e.g. sweep.resume, not the run's resume
            sweep[key[6:]] = value
        elif key in FLAT:
            run[key] = value
        elif key in algorithm_fields():  # a field of an algorithm without a flat name of its own (eta)
            own[key] = value
        elif key in SWEEP_TYPES:
            sweep[key] = value
        else:
            raise _unknown(key, [*FLAT, *SWEEP_TYPES], "the command-line options")
    if own:
        run["algorithm_params"] = {**(run.get("algorithm_params") or flat(config)["algorithm_params"] or {}), **own}
    exp = replace(exp, config=with_flat(config, **run), sweep=replace(exp.sweep, **sweep))
    check_choices(exp)
    return exp


def absolute_paths(config: RunConfig) -> RunConfig:
    """Problem, recording, edge-list and a user's algorithm's files as absolute paths, so that a saved config works
    from any directory."""
    over = {}
    p = config.problem
    if p.problem_file is not None:
        over["problem_file"] = _absolute(p.problem_file)
    if p.data is not None:
        over["data"] = _absolute(p.data)
    if p.policies is not None:
        over["policies"] = _absolute(p.policies)
    graph = config.network.graph
    if graph is not None and graph not in TOPOLOGIES and graph not in NAMES:
        over["graph"] = _absolute(graph)
    module, _, cls = (config.algorithm.name or "").rpartition(":")
    if module.endswith(".py"):  # a user's algorithm, path/to/file.py:Class
        over["algorithm"] = f"{_absolute(module)}:{cls}"
    return with_flat(config, **over)


def _absolute(path: str) -> str:
    """``path`` resolved, or only made absolute where a loop of symbolic links stops that (the file's reader then
    says what it is)."""
    try:
        resolved = Path(path).resolve()
    except (RuntimeError, OSError):
        return str(Path(path).absolute())
    # /dev/fd/N of a process substitution resolves to "pipe:[...]", a name no one can open: keep the one given
    return str(resolved if resolved.exists() or not Path(path).exists() else Path(path).absolute())


def _drop_none(d: dict) -> dict:
    return {k: v for k, v in d.items() if v is not None}


def to_data(exp: Experiment, *, output: bool = True, sweep: bool = True) -> dict:
    """The experiment as TOML-ready data, one table per section (None fields left out: TOML has no null)."""
    config = exp.config
    data = {}
    for name in SECTIONS:
        if name == "output" and not output:
            continue
        if name == "algorithm":
            table = _drop_none({"name": config.algorithm.name, **config.algorithm.fields})
        elif name == "output":
            table = _drop_none({k: v for k, v in asdict(config.output).items() if k != "resume" or v})
        else:
            table = _drop_none(asdict(getattr(config, name)))
        if table:
            data[name] = table
    if exp.grid:
        data["grid"] = exp.grid
    if sweep and exp.grid:
        data["sweep"] = _drop_none(vars(exp.sweep))
    return data


def to_toml(exp: Experiment, header: str = "", **kw) -> str:
    import tomli_w

    text = tomli_w.dumps(to_data(exp, **kw))
    return "".join(f"# {line}\n" for line in header.splitlines()) + text


def experiment_from(file: str | None, flags: dict) -> Experiment:
    """The experiment of a file (if any) with command-line ``flags`` (only those given) on top."""
    exp = load(file) if file is not None else Experiment()
    return override(exp, flags)
