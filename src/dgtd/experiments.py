"""Experiment files: a run or a sweep written down once as TOML, and read back exactly.

An experiment file is a TOML serialisation of a `dgtd.config.RunSpec` plus the output options of
``dgtd run``, and for ``dgtd sweep`` a ``[grid]`` table and a ``[sweep]`` table::

    scenario = "paper-example-1"        # or problem_file = "chain.npz", data = "transitions.parquet", or [env]
    algorithm = "dgtd"
    iterations = 20000
    seeds = 4
    alpha0 = 10.0
    out = "runs/example"                # output options: out, progress, plots, checkpoint_every, resume

    [env]                               # a user's simulator: dgtd.scenarios.user.EnvSpec's fields
    make = "mypackage.envs:make_env"    # (with gamma = 0.9 at the top level, as for data)
    features = "fourier:3"

    [params]                            # the scenario's own parameters, if it has any
    [algorithm_params]                  # algorithm fields beyond alpha0, beta, schedule, kappa, rho
    box_scale = 2.0

    [grid]                              # dgtd sweep: the runs are the product of these lists
    alpha0 = [1.0, 10.0]
    edge_prob = [0.5, 0.8]
    [grid.env]                          # (also grid.params, grid.algorithm_params)
    features = ["fourier:2", "fourier:3"]

    [sweep]                             # dgtd sweep: executor = "process" or "ray", address, workers, ...
    executor = "process"

Every command-line option of ``dgtd run`` and ``dgtd sweep`` is a field of the same name (dashes become
underscores) and a flag given on the command line overrides the file. Relative paths are taken from the
current directory, as on the command line; a resolved config records them as absolute paths. A field that
is not known, or has the wrong type, is an error naming it and the closest known field.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

from dgtd.config import RunSpec, check_type, closest, field_types
from dgtd.errors import DgtdInputError
from dgtd.graphs.topologies import TOPOLOGIES
from dgtd.run.loop import check_count

EXECUTORS = ("process", "ray")
TABLE_FORMATS = ("auto", "parquet", "csv")


@dataclass(frozen=True)
class Output:
    """How ``dgtd run`` reports and saves; none of these changes the numbers.

    - ``out``: results directory (default: runs/NAME of the problem).
    - ``progress``, ``plots``: progress bar on stderr; figures in the results directory.
    - ``checkpoint_every``: save the whole run state every K iterations (0: never), for ``resume``.
    - ``resume``: continue the run saved in ``out`` from its last checkpoint.
    - ``overwrite``: replace the results of another run (another configuration) in ``out``; without it that is
      refused. Rerunning the same configuration into its own directory needs no flag. Either way the previous
      run's files go first, so a directory never mixes two runs.
    """

    out: str | None = None
    progress: bool = True
    plots: bool = True
    checkpoint_every: int = 0
    resume: bool = False
    overwrite: bool = False


@dataclass(frozen=True)
class SweepOptions:
    """How ``dgtd sweep`` hands out its jobs (none of these changes the numbers).

    - ``executor``: 'process' (a pool of local processes) or 'ray'.
    - ``address``: a running Ray cluster (e.g. 'ray://head:10001' or 'auto'); default: start a local one.
    - ``workers``: jobs at once (default: the local cores; on a Ray cluster, its CPUs).
    - ``resume``: skip jobs already finished in ``out`` (default: on when the directory exists).
    - ``format``: the sweep's table, 'parquet' (needs pyarrow), 'csv', or 'auto' (parquet when possible).
    """

    executor: str = "process"
    address: str | None = None
    workers: int | None = None
    resume: bool | None = None
    format: str = "auto"


@dataclass(frozen=True)
class Experiment:
    """A run spec, its output options, and for a sweep its grid ({field: [values]}, with nested tables for
    ``params`` and ``algorithm_params``) and executor options."""

    spec: RunSpec = RunSpec()
    output: Output = Output()
    grid: dict = field(default_factory=dict)
    sweep: SweepOptions = SweepOptions()


SPEC_TYPES = field_types(RunSpec)
OUTPUT_TYPES = field_types(Output)
SWEEP_TYPES = field_types(SweepOptions)
TABLES = ("params", "algorithm_params", "env")
TOP_LEVEL = [*SPEC_TYPES, *OUTPUT_TYPES, "grid", "sweep"]


def _unknown(key: str, valid, where: str) -> DgtdInputError:
    return DgtdInputError(f"unknown field {key!r} in {where}{closest(key, valid)}")


def _grid(data: dict, where: str) -> dict:
    """Check a [grid] table: run fields mapped to non-empty lists of values of the field's type."""
    grid = {}
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
        if key not in SPEC_TYPES:
            raise _unknown(key, [*SPEC_TYPES], f"[grid] of {where}")
        if not isinstance(values, list) or not values:
            raise DgtdInputError(f"grid.{key} in {where} must be a non-empty list of values, e.g. {key} = [..]")
        grid[key] = [check_type(f"grid.{key} in {where}: each value", v, SPEC_TYPES[key]) for v in values]
    return grid


def parse(data: dict, where: str = "the experiment") -> Experiment:
    """An `Experiment` from the data of a TOML file (or any dict of the same shape)."""
    spec, output, sweep, grid = {}, {}, {}, {}
    for key, value in data.items():
        if key in SPEC_TYPES:
            spec[key] = check_type(f"field {key!r} in {where}", value, SPEC_TYPES[key])
        elif key in OUTPUT_TYPES:
            output[key] = check_type(f"field {key!r} in {where}", value, OUTPUT_TYPES[key])
        elif key == "grid":
            grid = _grid(check_type(f"[grid] in {where}", value, dict), where)
        elif key == "sweep":
            for k, v in check_type(f"[sweep] in {where}", value, dict).items():
                if k not in SWEEP_TYPES:
                    raise _unknown(k, SWEEP_TYPES, f"[sweep] of {where}")
                sweep[k] = check_type(f"sweep.{k} in {where}", v, SWEEP_TYPES[k])
        else:
            raise _unknown(key, TOP_LEVEL, where)
    exp = Experiment(RunSpec(**spec), Output(**output), grid, SweepOptions(**sweep))
    check_choices(exp)
    return exp


def check_choices(exp: Experiment) -> None:
    if exp.sweep.executor not in EXECUTORS:
        raise DgtdInputError(f"executor must be one of {', '.join(EXECUTORS)}, got {exp.sweep.executor!r}")
    if exp.sweep.format not in TABLE_FORMATS:
        raise DgtdInputError(f"format must be one of {', '.join(TABLE_FORMATS)}, got {exp.sweep.format!r}")
    if exp.sweep.workers is not None and exp.sweep.workers < 1:
        raise DgtdInputError(f"workers must be >= 1 (leave it out to use every core), got {exp.sweep.workers}")
    check_count("checkpoint_every", exp.output.checkpoint_every, 0)  # 0: no checkpoints


def load(path: str | Path) -> Experiment:
    """Read an experiment file; a missing file, bad TOML or a bad field is a one-line `DgtdInputError`."""
    path = Path(path)
    if path.is_dir():
        path = path / "config.toml"
    try:
        with open(path, "rb") as f:
            data = tomllib.load(f)
    except FileNotFoundError:
        raise DgtdInputError(f"experiment file {path} does not exist") from None
    except tomllib.TOMLDecodeError as e:
        raise DgtdInputError(f"{path} is not valid TOML: {e}") from None
    return parse(data, str(path))


ENV_FLAGS = {"env_make": "make", "features": "features", "split": "split"}
"""Command-line options that set a field of the [env] table (--env, --features, --split)."""
SCENARIO_FLAGS = ("agents", "policy")
"""Options that set the [env] field of their name in an env run, else the scenario's parameter (mpe-spread's)."""


def override(exp: Experiment, values: dict) -> Experiment:
    """``exp`` with the given fields replaced (command-line flags), each routed to the spec, output or sweep
    options; 'sweep.NAME' names a sweep option whose name a run option also has (resume). The --env flags
    (`ENV_FLAGS`) set fields of the [env] table, and ``agents`` and ``policy`` set those of an env run, else the
    scenario's parameters of those names."""
    parts = {"spec": {}, "output": {}, "sweep": {}}
    env = {ENV_FLAGS[k]: v for k, v in values.items() if k in ENV_FLAGS}
    shared = {k: values[k] for k in SCENARIO_FLAGS if values.get(k) is not None}
    if (env and "make" in env) or exp.spec.env is not None:
        parts["spec"]["env"] = {**(exp.spec.env or {}), **env, **shared}
    elif env:
        parts["spec"]["env"] = env  # flags of an env run without its env: `resolve` says so
    elif shared:
        parts["spec"]["params"] = {**(exp.spec.params or {}), **shared}
    for key, value in values.items():
        if key in ENV_FLAGS or key in SCENARIO_FLAGS:
            continue
        if key.startswith("sweep.") and key[6:] in SWEEP_TYPES:  # e.g. sweep.resume, not the run's resume
            parts["sweep"][key[6:]] = value
        elif key in SPEC_TYPES:
            parts["spec"][key] = value
        elif key in OUTPUT_TYPES:
            parts["output"][key] = value
        elif key in SWEEP_TYPES:
            parts["sweep"][key] = value
        else:
            raise _unknown(key, TOP_LEVEL, "the command-line options")
    exp = replace(
        exp,
        spec=replace(exp.spec, **parts["spec"]),
        output=replace(exp.output, **parts["output"]),
        sweep=replace(exp.sweep, **parts["sweep"]),
    )
    check_choices(exp)
    return exp


def absolute_paths(spec: RunSpec) -> RunSpec:
    """Problem and edge-list files as absolute paths, so that a saved config works from any directory."""
    over = {}
    if spec.problem_file is not None:
        over["problem_file"] = str(Path(spec.problem_file).resolve())
    if spec.data is not None:
        over["data"] = str(Path(spec.data).resolve())
    if spec.graph is not None and spec.graph not in TOPOLOGIES:
        over["graph"] = str(Path(spec.graph).resolve())
    return replace(spec, **over)


def _drop_none(d: dict) -> dict:
    return {k: v for k, v in d.items() if v is not None}


def to_data(exp: Experiment, *, output: bool = True, sweep: bool = True) -> dict:
    """The experiment as TOML-ready data (None fields left out: TOML has no null)."""
    first = ["scenario", "problem_file", "data", "gamma", "algorithm"]  # what is run, then how
    names = first + [f.name for f in fields(RunSpec) if f.name not in first]
    data = _drop_none({name: getattr(exp.spec, name) for name in names})
    if output:
        data.update(_drop_none({k: v for k, v in vars(exp.output).items() if k != "resume" or v}))
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
