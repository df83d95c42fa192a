"""A run described as plain data (`RunSpec`) and its resolution into library objects.

Every field may be left None to take the scenario's value; `resolve` returns the objects and the fully
resolved spec, which is what results directories record so that a run can be reproduced exactly.
Experiment files (`dgtd.experiments`) are TOML serialisations of a `RunSpec`.
"""

from __future__ import annotations

import difflib
import inspect
import types
import typing
from dataclasses import asdict, dataclass, fields, replace

from dgtd.algorithms.dgtd import DGTD
from dgtd.errors import DgtdInputError
from dgtd.graphs import topologies
from dgtd.graphs.random import random_edges
from dgtd.problems.io import file_digest, load_problem
from dgtd.problems.model import with_reward_noise
from dgtd.scenarios import get_scenario
from dgtd.run.loop import RunSettings
from dgtd.sources.model import Sampling


@dataclass(frozen=True)
class RunSpec:
    """One run, as data. ``scenario`` or ``problem_file`` names the problem.

    ``algorithm`` names an entry of `dgtd.algorithms.ALGORITHMS` (default: the scenario's); ``alpha0`` ..
    ``rho`` set the fields of that name of its config and ``algorithm_params`` any other field (e.g.
    ``box_scale``). ``params`` are the scenario's own keyword arguments (``edge_prob`` stays a field of its own).
    Defaults of the run's length and seeds are `RunSettings`'; None takes the scenario's value. The command-line
    options of ``dgtd run`` take their defaults and choices from here (`dgtd.cli.spec_default`, `CHOICES`).
    """

    scenario: str | None = None
    problem_file: str | None = None
    graph: str | None = None
    edge_prob: float | None = None
    iterations: int | None = None
    seeds: int = RunSettings.seeds
    seed: int = RunSettings.seed
    alpha0: float | None = None
    beta: float | None = None
    schedule: str | None = None
    kappa: float | None = None
    rho: float | None = None
    sampling: str | None = None
    shared: bool | None = None
    reward_noise: str | None = None
    backend: str = RunSettings.backend
    checkpoints: int = RunSettings.checkpoints
    tail_fraction: float = RunSettings.tail_fraction
    block_size: int = RunSettings.block_size
    algorithm: str | None = None
    params: dict | None = None
    algorithm_params: dict | None = None

    def to_dict(self) -> dict:
        return asdict(self)


ALGORITHM_FIELDS = ("alpha0", "beta", "schedule", "kappa", "rho")


def _choices() -> dict:
    from dgtd.algorithms.stepsizes import SCHEDULES
    from dgtd.problems.model import REWARD_NOISES
    from dgtd.run.loop import BACKENDS
    from dgtd.sources.model import SAMPLING_MODES

    return {"schedule": SCHEDULES, "sampling": SAMPLING_MODES, "reward_noise": REWARD_NOISES, "backend": BACKENDS}


CHOICES = _choices()
"""RunSpec field -> its valid values, from the modules that check them."""
STEP_SIZE_FIELDS = ("alpha0", "beta", "schedule")


def closest(name: str, valid) -> str:
    """'; did you mean X?' for the valid name closest to a misspelt one, else ''."""
    close = difflib.get_close_matches(name, list(valid), n=1, cutoff=0.5)
    return f"; did you mean {close[0]!r}?" if close else ""


_TYPE_WORDS = {int: "an integer", float: "a number", str: "a string", bool: "true or false", dict: "a table",
               list: "a list", tuple: "a list"}


def check_type(where: str, value, hint) -> object:
    """``value`` as the type ``hint`` asks (ints are accepted for floats), or a `DgtdInputError` naming ``where``."""
    options = typing.get_args(hint) if typing.get_origin(hint) in (typing.Union, types.UnionType) else (hint,)
    for t in options:
        base = typing.get_origin(t) or t
        if t is type(None):
            if value is None:
                return None
        elif base is float and isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        elif base is int and isinstance(value, int) and not isinstance(value, bool):
            return value
        elif base in (list, tuple) and isinstance(value, (list, tuple)):
            return tuple(value) if base is tuple else list(value)
        elif base in (str, bool, dict) and isinstance(value, base):
            return value
    wanted = " or ".join(_TYPE_WORDS.get(typing.get_origin(t) or t, str(t)) for t in options if t is not type(None))
    raise DgtdInputError(f"{where} must be {wanted}, got {value!r} ({type(value).__name__})")


def field_types(cls) -> dict:
    """Field name -> type hint of a dataclass (string annotations evaluated)."""
    hints = typing.get_type_hints(cls)
    return {f.name: hints[f.name] for f in fields(cls)}


def _network(graph: str, n_agents: int, edge_prob: float):
    from pathlib import Path

    if graph in topologies.TOPOLOGIES:
        base = topologies.TOPOLOGIES[graph](n_agents)
    elif not Path(graph).is_file():
        raise DgtdInputError(f"graph {graph!r} is neither a known graph nor an edge-list file (known graphs: "
                             f"{', '.join(topologies.TOPOLOGIES)}){closest(Path(graph).name, topologies.TOPOLOGIES)}")
    else:
        base = topologies.read_edge_list(graph)
        if base.n_nodes > n_agents:
            raise DgtdInputError(f"edge list {graph} names agent {base.n_nodes - 1} but the problem has {n_agents} agents")
        base = topologies.from_edges(n_agents, base.edges, base.name)
    return random_edges(base, edge_prob)


def resolve(spec: RunSpec):
    """(problem, network, algorithm, sampling, settings, resolved spec) for a spec."""
    if (spec.scenario is None) == (spec.problem_file is None):
        raise DgtdInputError("name exactly one problem: a scenario (e.g. paper-example-1) or --problem FILE.npz")
    params = None
    if spec.scenario is not None:
        kwargs, params, edge_prob = scenario_arguments(spec.scenario, spec.params or {}, spec.edge_prob)
        sc = get_scenario(spec.scenario, **kwargs)
        problem, network, algorithm, sampling, iterations = sc.problem, sc.network, sc.algorithm, sc.sampling, sc.iterations
        graph = None  # the scenario's own network, rebuilt from the same parameters
        if sc.source is not None:
            _refuse_model_overrides(spec, sc)  # its source sets the links, states and rewards
        if spec.edge_prob is not None and "edge_prob" not in kwargs and spec.graph is None:
            if not hasattr(network, "base"):
                raise DgtdInputError(f"scenario {spec.scenario!r} has no random-edge network, so edge_prob does not apply; remove it")
            network, edge_prob = random_edges(network.base, spec.edge_prob), spec.edge_prob
        if spec.reward_noise not in (None, problem.reward_noise):
            problem = with_reward_noise(problem, spec.reward_noise)
    else:
        if spec.params:
            raise DgtdInputError("params are a scenario's parameters, but this run reads a problem file; remove them")
        problem = load_problem(spec.problem_file, reward_noise=spec.reward_noise or "none")
        graph, edge_prob, iterations = "ring", 1.0, 100_000
        algorithm, sampling, network = DGTD(), Sampling(), None
    if spec.graph is not None or network is None:
        graph = spec.graph or graph
        edge_prob = spec.edge_prob if spec.edge_prob is not None else (edge_prob if edge_prob is not None else 1.0)
        network = _network(graph, problem.n_agents, edge_prob)
    algorithm = build_algorithm(spec, algorithm)
    sampling = Sampling(mode=spec.sampling or sampling.mode, shared=sampling.shared if spec.shared is None else spec.shared)
    settings = RunSettings(
        iterations=int(iterations if spec.iterations is None else spec.iterations), seeds=spec.seeds, seed=spec.seed, checkpoints=spec.checkpoints,
        tail_fraction=spec.tail_fraction, block_size=spec.block_size, backend=spec.backend,
    )
    own = field_types(type(algorithm))
    resolved = replace(
        spec, graph=graph, edge_prob=edge_prob, iterations=settings.iterations,
        **{k: getattr(algorithm, k) if k in own else None for k in ALGORITHM_FIELDS},
        sampling=sampling.mode, shared=sampling.shared, reward_noise=problem.reward_noise, algorithm=algorithm.name,
        params=params,
        algorithm_params={k: _plain(getattr(algorithm, k)) for k in own
                          if k not in ALGORITHM_FIELDS and getattr(algorithm, k) is not None} or None,
    )
    return problem, network, algorithm, sampling, settings, resolved


def _refuse_model_overrides(spec: RunSpec, sc) -> None:
    """A scenario with its own sample source sets the links, states and rewards itself: flags that would change
    them could not apply, so they are refused (values equal to the scenario's own, as recorded, are accepted)."""
    own = {"--graph": None, "--sampling": sc.sampling.mode, "--shared": sc.sampling.shared,
           "--reward-noise": sc.problem.reward_noise}
    given = [flag for flag, value in (("--graph", spec.graph), ("--sampling", spec.sampling), ("--shared", spec.shared),
                                      ("--reward-noise", spec.reward_noise)) if value is not None and value != own[flag]]
    if given:
        raise DgtdInputError(f"scenario {spec.scenario} simulates its own samples and links; {', '.join(given)} "
                             f"{'does' if len(given) == 1 else 'do'} not apply to it (leave {'it' if len(given) == 1 else 'them'} out)")


def scenario_of(spec: RunSpec):
    """The named `Scenario` of a spec (cached by its builder where building is costly), or None for a problem file."""
    return None if spec.scenario is None else get_scenario(spec.scenario)


def make_source(spec: RunSpec, settings: RunSettings):
    """A fresh sample source for a run of ``spec``, or None when samples come from the model (`ModelSource`).

    Scenarios that simulate a world (e.g. paper-example-2's robots and their proximity links) supply their own;
    pass it as ``run(..., source=make_source(spec, settings))``. Each call starts the same streams again, so
    two algorithms given fresh sources with one seed see identical samples and links.
    """
    sc = scenario_of(spec)
    if sc is None or sc.source is None:
        return None
    return sc.source(settings.seed, range(settings.seeds))


def _plain(x):
    return list(x) if isinstance(x, tuple) else x


def scenario_arguments(name: str, params: dict, edge_prob: float | None):
    """(keyword arguments for the scenario's factory, its full parameters less edge_prob, edge_prob used).

    Parameters not given take the factory's defaults, and the resolved spec records them all, so that a
    later change of a default does not change what a saved config means.
    """
    from dgtd.scenarios import SCENARIOS

    if name not in SCENARIOS:
        get_scenario(name)  # raises the error that lists the known names
    sig = inspect.signature(SCENARIOS[name])
    names = [p.name for p in sig.parameters.values() if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]
    for k in params:
        if k == "edge_prob":
            raise DgtdInputError("edge_prob is a field of its own: write it at the top level, not under params")
        if k not in names:
            known = ", ".join(n for n in names if n != "edge_prob") or "none"
            raise DgtdInputError(f"scenario {name!r} has no parameter {k!r}{closest(k, names)} (its parameters: {known})")
    kwargs = {p.name: p.default for p in sig.parameters.values() if p.name in names and p.default is not p.empty}
    kwargs.update(params)
    if edge_prob is not None and "edge_prob" in names:
        kwargs["edge_prob"] = edge_prob
    missing = [n for n in names if n not in kwargs]
    if missing:
        raise DgtdInputError(f"scenario {name!r} needs parameter(s) {', '.join(missing)} under params")
    rest = {k: _plain(v) for k, v in kwargs.items() if k != "edge_prob"}
    return kwargs, rest or None, kwargs.get("edge_prob")


def build_algorithm(spec: RunSpec, default):
    """The config of ``spec.algorithm`` (default: the scenario's own), with the spec's fields set on it.

    Another algorithm than the scenario's starts from its own defaults and the scenario's step sizes
    (alpha0, beta, schedule) where it has those fields. A field the algorithm lacks is an error.
    """
    from dgtd.algorithms import ALGORITHMS

    name = spec.algorithm or default.name
    if name not in ALGORITHMS:
        raise DgtdInputError(f"unknown algorithm {name!r}{closest(name, ALGORITHMS)} (known: {', '.join(ALGORITHMS)})")
    cls = ALGORITHMS[name]
    own = field_types(cls)
    if isinstance(default, cls):
        algorithm = default
    else:
        algorithm = cls(**{k: getattr(default, k) for k in STEP_SIZE_FIELDS if k in own and hasattr(default, k)})
    over = {}
    for k in ALGORITHM_FIELDS:
        if getattr(spec, k) is not None:
            if k not in own:
                raise DgtdInputError(f"algorithm {name!r} has no parameter {k!r} (its parameters: {', '.join(own)}); remove it")
            over[k] = getattr(spec, k)
    for k, v in (spec.algorithm_params or {}).items():
        if k in ALGORITHM_FIELDS:
            raise DgtdInputError(f"{k} is a field of its own: write it at the top level, not under algorithm_params")
        if k not in own:
            raise DgtdInputError(f"algorithm {name!r} has no parameter {k!r}{closest(k, own)} (its parameters: {', '.join(own)})")
        over[k] = check_type(f"algorithm_params.{k}", v, own[k])
    return replace(algorithm, **over)


def spec_record(spec: RunSpec) -> dict:
    """The resolved spec as JSON-ready data, with the problem file's SHA-256 when there is one."""
    d = spec.to_dict()
    if spec.problem_file is not None:
        d["problem_sha256"] = file_digest(spec.problem_file)
    return d
