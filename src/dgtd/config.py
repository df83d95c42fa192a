"""One run configuration, `RunConfig`: what the agents evaluate, over which network, with which algorithm, how they
sample, for how long, and where the results go. It is at once the experiment file (TOML, one table per section:
`dgtd.experiments`), the Python API's argument (`dgtd.execute`) and what the command line's options set (each
option is a field, named as in `FLAT`; tests/config/test_config_cli.py checks their defaults and choices).

Every field may be left None to take the scenario's value (or the library's default); `resolve` returns the library
objects and the fully resolved config, which is what results directories record, so that a run can be reproduced
exactly. The run loop's own working state (`dgtd.run.loop.Context`, `dgtd.cli.job.PreparedRun`) stays separate.
"""

from __future__ import annotations

import difflib
import inspect
import types
import typing
from dataclasses import asdict, dataclass, field, fields, is_dataclass, make_dataclass, replace
from functools import lru_cache
from pathlib import Path
from types import SimpleNamespace
from typing import Any, NamedTuple

from dgtd.algorithms.dgtd import DGTD
from dgtd.errors import DgtdInputError
from dgtd.fields import STEP_SIZES, option
from dgtd.graphs import chunked, topologies
from dgtd.graphs.random import random_edges
from dgtd.problems.io import file_digest, load_problem
from dgtd.problems.model import with_restarts, with_reward_noise
from dgtd.run.settings import RunSettings, check_count
from dgtd.scenarios import get_scenario
from dgtd.sources.model import Sampling

DEFAULT_GAMMA = 0.9  # of an --env or --data run, when not given


@dataclass(frozen=True)
class ProblemConfig:
    """What the agents evaluate: exactly one of ``scenario`` (a name `dgtd scenarios` lists), ``problem_file`` (an
    .npz model), ``env`` (a user's simulator: the fields of `dgtd.scenarios.user.EnvSpec`) or ``data`` (recorded
    transitions): a tagged choice, checked by `resolve`. ``gamma`` is the discount of an env or data run; ``params``
    the scenario's own keyword arguments; ``reward_noise`` and ``restarts`` (an episodic task's convention,
    `dgtd.problems.model.Problem`) change how a model's samples are drawn."""

    scenario: str | None = None  # the commands' argument SCENARIO
    problem_file: str | None = field(
        default=None,
        metadata=option(
            "An .npz with arrays P (S,S), R (N,S), Phi (S,q) and scalar gamma, instead of a scenario.",
            flags=("--problem",),
        ),
    )
    policies: str | None = field(
        default=None,
        metadata=option(
            "A learning run's folder (dgtd learn --out) or its policies.npz: the agents of the multi-agent MDP file "
            "it learnt on (--problem) evaluate the policies it ended with, not the file's policy_k.",
            metavar="DIR",
        ),
    )
    policies_seed: int | None = field(
        default=None, metadata=option("Which seed's policies --policies takes (default 0).", metavar="K")
    )
    env: dict | None = None  # the fields of EnvSpec, each an option of its own (--env sets make)
    data: str | None = field(
        default=None,
        metadata=option(
            "Run on recorded transitions (.parquet, .csv, .npz; columns seed, step, agent, phi_j, next_phi_j (or "
            "state, next_state), reward, and optionally ratio, terminal): one recording per seed.",
            metavar="FILE",
        ),
    )
    gamma: float | None = field(
        default=None, metadata=option(f"Discount factor of an --env or --data run (default {DEFAULT_GAMMA}).")
    )
    params: dict | None = None  # a scenario's own keyword arguments: a table of an experiment file
    reward_noise: str | None = field(
        default=None,
        metadata=option(
            "How a sample's reward is drawn: its mean E[r | s, a] (none, the default), random in [0, sigma] with "
            "that mean (bernoulli, uniform), or the reward of the sampled transition r(s, a, s') where the problem "
            "gives rewards per transition (transition)."
        ),
    )
    restarts: str | None = field(
        default=None,
        metadata=option(
            "An episodic task's restart transition (terminal state to the next episode's start) is a sample, as dgtd "
            "counts it (sampled, the default), or not, as RL-Glue based suites count it (skipped; d then weights the "
            "non-terminal states only). See README, Episodic tasks."
        ),
    )


@dataclass(frozen=True)
class NetworkConfig:
    """Who hears whom: ``graph`` (a topology of `dgtd.graphs.topologies` or a file of 'i j' edge lines; default the
    scenario's, else ring), each of whose edges is up with probability ``edge_prob`` at each step; ``loss``, the
    probability that a message is lost (`dgtd.channels.lossy.loss_per_arc`: one for all, one per receiving agent,
    or a file of 'i j p' lines), none by default; ``burst``, the mean length of a burst of losses (per arc, with the
    same long-run loss: `dgtd.channels.Lossy`), none by default (each message lost independently); ``reweight``,
    whether each agent weighs what it hears by 1 / (1 - loss), which gives the Laplacian methods back w*; and
    `dgtd.channels.Imperfect`'s late, asleep and compressed messages: ``delay`` (the most steps a message is late,
    0 by default), ``wake`` (each agent's probability of being awake at a step: one for all or one per agent, 1 by
    default), ``bits`` (per number sent, 64 by default: exact), ``top_k`` (the coordinates a message keeps, all by
    default) and ``error_feedback`` (CHOCO's public copies, off by default)."""

    graph: str | None = field(
        default=None,
        metadata=option(
            "ring, path, star, complete, erdos-renyi (complete, each link up with --edge-prob), small-world "
            "(Watts-Strogatz), sparse-random (a fixed Erdos-Renyi graph of --mean-degree), geometric (agents uniform "
            "in the unit square, linked within the radius of --mean-degree), or a file of 'i j' edge lines (default: "
            "the scenario's, else ring)."
        ),
    )
    mean_degree: float | None = field(
        default=None,
        metadata=option(
            "small-world: the ring lattice's links an agent, k (even; default 4, 2 on 3 or 4 agents); "
            "sparse-random and geometric: the mean degree (default 2 ln N, rounded up)."
        ),
    )
    rewire: float | None = field(
        default=None, metadata=option("small-world: the probability that a lattice link is moved (default 0.1).")
    )
    graph_seed: int | None = field(
        default=None,
        metadata=option(
            "The seed of a small-world, sparse-random or geometric graph, drawn once from keyed streams: the same "
            "graph for every seed of the run (default 0)."
        ),
    )
    edge_prob: float | None = field(
        default=None, metadata=option("Probability that each edge of the graph is up at each step (1 = fixed graph).")
    )
    loss: float | list | str | None = field(
        default=None,
        metadata=option(
            "Each message is lost with probability P; or agent i misses each message sent to it with probability Pi "
            "(one per agent); or a file of 'i j p' lines (agent i misses j's messages with probability p). Default: "
            "none lost. See docs/links.md.",
            metavar="P|P1,...,PN|FILE",
        ),
    )
    burst: float | None = field(
        default=None,
        metadata=option(
            "Lost messages come in bursts of mean length L on each link (Gilbert-Elliott), with the same long-run "
            "loss as --loss. Default: each message lost independently.",
            metavar="L",
        ),
    )
    reweight: bool | None = field(
        default=None,
        metadata=option(
            "Each agent weighs what it hears from j by 1 / (1 - loss of j's messages to it): the Laplacian methods "
            "(dgtd, pd-td) then converge to w* under any --loss. Default: no."
        ),
    )
    delay: int | None = field(
        default=None,
        metadata=option(
            "Each message arrives d steps late, d uniform in 0..D; a receiver uses the newest it holds from each "
            "neighbour. Default: 0.",
            metavar="D",
        ),
    )
    wake: float | list | str | None = field(
        default=None,
        metadata=option(
            "Each agent is awake at a step with probability Q (or Qi, one per agent); asleep, it neither updates "
            "nor sends, and its neighbours use the last they heard. Default: 1.",
            metavar="Q|Q1,...,QN",
        ),
    )
    bits: int | None = field(
        default=None,
        metadata=option(
            "Each number sent is rounded stochastically to B bits, the message's scale sent alongside. Default: 64 "
            "(exact).",
            metavar="B",
        ),
    )
    top_k: int | None = field(
        default=None,
        metadata=option(
            "Each message keeps its K largest coordinates (with their indices). Default: all.", metavar="K"
        ),
    )
    error_feedback: bool | None = field(
        default=None,
        metadata=option(
            "Send the compressed difference from a copy both ends keep (CHOCO-gossip), so that what is not sent now "
            "is sent later. Default: no."
        ),
    )


@dataclass(frozen=True)
class AlgorithmConfig:
    """``name``, a key of `dgtd.algorithms.ALGORITHMS` (default: the scenario's) or a user's class
    (``path/to/file.py:Class``, `algorithm_class`), and ``fields`` to set on its
    config: any field of that dataclass (alpha0, beta, schedule, kappa, rho, box_scale, ...), checked against it by
    `resolve`; the others keep the scenario's values. In an experiment file they sit beside ``name`` in
    [algorithm]; on the command line every registered algorithm's field is an option (--alpha0, --kappa, --eta, ...:
    `dgtd.cli.options.ALGORITHM_OPTIONS`)."""

    name: str | None = field(
        default=None,
        metadata=option(
            "Algorithm name (default: the scenario's, dgtd), or your own as path/to/file.py:Class (checked by "
            "dgtd.check_algorithm first).",
            flags=("--algorithm",),
        ),
    )
    fields: dict = field(default_factory=dict)  # each registered algorithm's field an option of its own


def _optional(cls, name: str, doc: str):
    """A frozen dataclass with ``cls``'s fields, each optional with default None ('the scenario's value, else
    ``cls``'s default'): the configuration's section for ``cls`` without declaring its fields a second time."""
    hints = typing.get_type_hints(cls)
    section = make_dataclass(
        name,
        [(f.name, hints[f.name] | None, field(default=None, metadata=f.metadata)) for f in fields(cls)],
        frozen=True,
    )
    section.__module__, section.__doc__ = __name__, doc
    return section


SamplingConfig = _optional(
    Sampling,
    "SamplingConfig",
    "How the agents see the chain: the fields of `dgtd.sources.model.Sampling`; None takes the scenario's.",
)
RunLength = _optional(
    RunSettings,
    "RunLength",
    "How long and how many: the fields of `dgtd.run.loop.RunSettings` (iterations, seeds, seed, checkpoints, "
    "tail_fraction, block_size, backend); None takes the scenario's iterations and RunSettings' other defaults.",
)


@dataclass(frozen=True)
class Output:
    """How a run reports and saves; none of these changes the numbers.

    - ``out``: results directory (default: runs/NAME of the problem).
    - ``progress``, ``plots``: progress bar on stderr; figures in the results directory.
    - ``checkpoint_every``: save the whole run state every K iterations (0: never), for ``resume``.
    - ``resume``: continue the run saved in ``out`` from its last checkpoint.
    - ``log``: where else the metrics go: ``tensorboard``, ``mlflow`` or both (`dgtd.run.logs`).
    - ``overwrite``: replace the results of another run (another configuration) in ``out``; without it that is
      refused. Rerunning the same configuration into its own directory needs no flag: a run cut off after a
      checkpoint continues from it (as ``resume`` would), a finished one runs afresh; ``overwrite`` starts afresh
      in any case. Either way the previous run's files go first, so a directory never mixes two runs.
    """

    out: str | None = field(default=None, metadata=option("Results directory (default: runs/NAME)."))
    progress: bool = field(default=True, metadata=option("A progress bar on stderr."))
    plots: bool = field(default=True, metadata=option("Figures in the results directory."))
    checkpoint_every: int = field(
        default=0,
        metadata=option(
            "Save the whole run state every K iterations to OUT/checkpoint.npz (0: never); the same command again "
            "continues from it."
        ),
    )
    log: str | None = field(
        default=None,
        metadata=option(
            "Also log every metric at every checkpoint, one run per seed, to tensorboard (event files in "
            "OUT/tensorboard), mlflow (the local store OUT/mlflow.db) or both (tensorboard,mlflow); extras "
            "dgtd[tensorboard], dgtd[mlflow].",
            metavar="tensorboard,mlflow",
        ),
    )
    resume: bool = False  # set by --resume DIR, which names the results directory too
    overwrite: bool = field(
        default=False,
        metadata=option(
            "Replace the results or checkpoint of another run in OUT (refused without it), or start this run afresh "
            "(without it, a run cut off after a checkpoint continues; a finished one is redone)."
        ),
    )

    def __post_init__(self):
        object.__setattr__(self, "checkpoint_every", check_count("checkpoint_every", self.checkpoint_every, 0))
        if self.resume and self.overwrite:  # one continues the saved run, the other starts afresh
            raise DgtdInputError(
                "--resume continues the saved run and --overwrite starts it afresh: give one of them, not both"
            )
        if self.log is not None:
            from dgtd.run.logs import log_kinds

            object.__setattr__(self, "log", ",".join(log_kinds(self.log)) or None)


@dataclass(frozen=True)
class RunConfig:
    """One run, as data: its sections are the tables of an experiment file.

    ``dgtd.execute(RunConfig(ProblemConfig(scenario="paper-example-1"), run=RunLength(seeds=4)))`` runs it as
    ``dgtd run paper-example-1 --seeds 4`` does."""

    problem: ProblemConfig = ProblemConfig()
    network: NetworkConfig = NetworkConfig()
    algorithm: AlgorithmConfig = AlgorithmConfig()
    sampling: SamplingConfig = SamplingConfig()  # type: ignore[valid-type]
    run: RunLength = RunLength()  # type: ignore[valid-type]
    output: Output = Output()


SECTIONS = {
    "problem": ProblemConfig,
    "network": NetworkConfig,
    "algorithm": AlgorithmConfig,
    "sampling": SamplingConfig,
    "run": RunLength,
    "output": Output,
}
"""Section name -> its dataclass: the tables of an experiment file."""

ALGORITHM_FIELDS = ("alpha0", "beta", "schedule", "kappa", "rho")
"""The algorithm fields that have options of their own (--alpha0 ...) and flat names of their own."""
FLAT_ALIASES = {"algorithm": ("algorithm", "name"), "sampling": ("sampling", "mode")}


def algorithm_fields() -> tuple:
    """The field names of the registered algorithms (each an option: `dgtd.cli.options.ALGORITHM_OPTIONS`); those not
    in `ALGORITHM_FIELDS` are kept in the algorithm's params (``algorithm_params``)."""
    from dgtd.algorithms import ALGORITHMS

    return tuple(dict.fromkeys(f.name for cls in ALGORITHMS.values() for f in fields(cls)))


def _flat_names() -> dict:
    """Flat name -> (section, field): the command line's options (dashes as underscores), a [grid]'s keys and the
    top-level keys of an experiment file in the older flat layout, which is still read."""
    out = {}
    for section, cls in SECTIONS.items():
        for f in fields(cls):
            if section != "algorithm" and (section, f.name) not in FLAT_ALIASES.values():
                out[f.name] = (section, f.name)
    out.update(FLAT_ALIASES)
    out.update({k: ("algorithm", k) for k in ALGORITHM_FIELDS})
    out["algorithm_params"] = ("algorithm", "params")  # every other field of the algorithm, as one table
    return out


FLAT = _flat_names()


def flat(config: RunConfig) -> dict:
    """The run's fields (all but the output's) by their flat names: what results files record (summary.json's
    config, a checkpoint's), and the keys a sweep's grid and the command line's options set."""
    d = {}
    for name, (section, key) in FLAT.items():
        if section == "output":
            continue
        if section == "algorithm" and key != "name":
            fields_ = config.algorithm.fields
            d[name] = (
                fields_.get(key)
                if key != "params"
                else {k: v for k, v in fields_.items() if k not in ALGORITHM_FIELDS} or None
            )
        else:
            d[name] = getattr(getattr(config, section), key)
    return d


def unflat(values: dict, output: Output | None = None) -> RunConfig:
    """The `RunConfig` of flat ``values`` (`flat`'s, or output fields too); names not in `FLAT` are an error."""
    parts: dict = {section: {} for section in SECTIONS}
    algorithm_fields: dict = {}
    for name, value in values.items():
        if name not in FLAT:
            raise DgtdInputError(f"unknown field {name!r}{closest(name, FLAT)}")
        section, key = FLAT[name]
        if section == "algorithm" and key == "params":
            algorithm_fields.update(value or {})
        elif section == "algorithm" and key != "name":
            if value is not None:
                algorithm_fields[key] = value
        else:
            parts[section][key] = value
    parts["algorithm"]["fields"] = algorithm_fields
    sections = {name: SECTIONS[name](**kw) for name, kw in parts.items() if name != "output"}
    out = replace(output or Output(), **parts["output"])
    return RunConfig(**sections, output=out)


def with_flat(config: RunConfig, **values) -> RunConfig:
    """``config`` with fields replaced by their flat names, its output's too (None clears a run field: the scenario's
    value again)."""
    return unflat({**flat(config), **values}, config.output)


def _choices() -> dict:
    from dgtd.algorithms.stepsizes import SCHEDULES
    from dgtd.problems.model import RESTARTS, REWARD_NOISES
    from dgtd.run.loop import BACKENDS
    from dgtd.sources.model import SAMPLING_MODES

    return {
        "schedule": SCHEDULES,
        "sampling": SAMPLING_MODES,
        "reward_noise": REWARD_NOISES,
        "restarts": RESTARTS,
        "backend": BACKENDS,
    }


CHOICES = _choices()
"""Flat field name -> its valid values, from the modules that check them."""
STEP_SIZE_FIELDS = STEP_SIZES


def closest(name: str, valid) -> str:
    """'; did you mean X?' for the valid name closest to a misspelt one, else ''."""
    close = difflib.get_close_matches(name, list(valid), n=1, cutoff=0.5)
    return f"; did you mean {close[0]!r}?" if close else ""


_TYPE_WORDS = {
    int: "an integer",
    float: "a number",
    str: "a string",
    bool: "true or false",
    dict: "a table",
    list: "a list",
    tuple: "a list",
}


def check_type(where: str, value, hint) -> Any:
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


SHAPE = ("mean_degree", "rewire", "graph_seed")  # what shapes a chunked graph


def _network(graph: str, n_agents: int, edge_prob: float, shape: dict | None = None):
    """The network of --graph over ``n_agents``, each link up with ``edge_prob``; ``shape`` the chunked graphs'
    fields (`SHAPE`: None where not given), refused for a graph they do not shape."""
    from pathlib import Path

    given = [f"--{k.replace('_', '-')}" for k, v in (shape or {}).items() if v is not None]
    if graph in chunked.NAMES:
        base = chunked.whole(
            chunked.ChunkedGraph(chunked.NAMES[graph], n_agents, **chunked_shape(graph, n_agents, shape or {}))
        )
        return random_edges(topologies.from_edges(n_agents, base.edges, graph, base.near), edge_prob)
    if given:
        raise DgtdInputError(f"{', '.join(given)} shape a small-world, sparse-random or geometric graph, not {graph!r}")
    if graph in topologies.TOPOLOGIES:
        base = topologies.TOPOLOGIES[graph](n_agents)
    elif not Path(graph).is_file():
        known = [*topologies.TOPOLOGIES, *chunked.NAMES]
        raise DgtdInputError(
            f"graph {graph!r} is neither a known graph nor an edge-list file (known graphs: "
            f"{', '.join(known)}){closest(Path(graph).name.lower(), known)}"
        )
    else:
        base = topologies.read_edge_list(graph)
        if base.n_nodes > n_agents:
            raise DgtdInputError(
                f"edge list {graph} names agent {base.n_nodes - 1} but the problem has {n_agents} agents"
            )
        base = topologies.from_edges(n_agents, base.edges, base.name)
    return random_edges(base, edge_prob)


def chunked_shape(graph: str, n_agents: int, shape: dict) -> dict:
    """The fields of a chunked graph (`dgtd.graphs.chunked.ChunkedGraph`) from the options, defaults filled in."""
    import math

    degree = shape.get("mean_degree")
    if degree is None:  # (small-world: k = 4, or the largest even k a few agents allow)
        most = max(n_agents - 1, 0)
        degree = min(4, most - most % 2) if graph == "small-world" else min(most, math.ceil(2 * math.log(n_agents)))
    rewire = shape.get("rewire")
    if graph != "small-world" and rewire is not None:
        raise DgtdInputError(f"--rewire moves a small-world graph's links; a {graph} graph has none to move")
    return {
        "mean_degree": float(degree),
        "rewire": 0.1 if rewire is None else float(rewire),
        "seed": check_count("graph_seed", shape.get("graph_seed") or 0, 0),
    }


PROBLEM_FIELDS = ("scenario", "problem_file", "env", "data")


class ResolvedRun(NamedTuple):
    """A run's configuration resolved once (`resolve`): the library's objects every command and the Python API run
    with, and the fully resolved config (every None given its value) that reproduces them."""

    problem: Any
    network: Any
    algorithm: Any
    sampling: Sampling
    settings: RunSettings
    config: RunConfig
    channel: Any  # the links' model over ``network`` (`dgtd.channels`), built once


def resolve(config: RunConfig) -> ResolvedRun:
    """A config resolved (`ResolvedRun`): every field checked, each None given the scenario's value, the library's
    objects built, the channel once."""
    spec = view(config)
    _check_problem_fields(spec)
    if spec.scenario is not None:
        base = _from_scenario(spec)
    elif spec.problem_file is not None:
        base = _from_problem_file(spec)
    else:
        base = _from_env_or_data(spec)
    spec, problem, network, algorithm, sampling, iterations, graph, edge_prob, params, env = base
    if spec.graph is not None or network is None:
        graph = spec.graph or graph
        edge_prob = spec.edge_prob if spec.edge_prob is not None else (edge_prob if edge_prob is not None else 1.0)
        network = _network(graph or "ring", problem.n_agents, edge_prob, {k: getattr(spec, k) for k in SHAPE})
    elif any(getattr(spec, k) is not None for k in SHAPE):
        raise DgtdInputError(
            "--mean-degree, --rewire and --graph-seed shape a --graph small-world, sparse-random or geometric"
        )
    loss = _loss(spec.loss)
    wake = _loss(spec.wake)  # a probability or a list, as a loss is written
    channel = channel_for(loss, spec.burst, network, spec.reweight, _links(spec, wake))  # built once, here
    algorithm = build_algorithm(spec, algorithm)
    if steps_from_the_problem(spec):
        algorithm = algorithm.from_the_problem(moments_of(problem), network)[0]
    sampling = Sampling(
        mode=spec.sampling or sampling.mode, shared=sampling.shared if spec.shared is None else spec.shared
    )
    run_given = {k: v for k, v in asdict(config.run).items() if v is not None}
    settings = RunSettings(**{"iterations": iterations, **run_given})
    own = field_types(type(algorithm))
    resolved = dict(
        vars(spec),
        **asdict(settings),
        graph=graph,
        edge_prob=edge_prob,
        loss=loss,
        burst=spec.burst,
        reweight=spec.reweight,
        wake=wake,
        **{k: getattr(algorithm, k) if k in own else None for k in ALGORITHM_FIELDS},
        sampling=sampling.mode,
        shared=sampling.shared,
        reward_noise=problem.reward_noise,
        # an episodic model's convention where it is not the default (records from before it existed stay equal)
        restarts=None if getattr(problem, "restarts", "sampled") == "sampled" else problem.restarts,
        algorithm=spec.algorithm if spec.algorithm and ":" in spec.algorithm else algorithm.name,  # a user's class
        params=params,
        env=_plain_env(env),
        algorithm_params={
            k: _plain(getattr(algorithm, k))
            for k in own
            if k not in ALGORITHM_FIELDS and getattr(algorithm, k) is not None
        }
        or None,
    )
    return ResolvedRun(problem, network, algorithm, sampling, settings, unflat(resolved, config.output), channel)


class _Base(NamedTuple):
    """What a run's problem gives before the config's own fields are applied (`resolve`)."""

    spec: Any
    problem: Any
    network: Any
    algorithm: Any
    sampling: Sampling
    iterations: int
    graph: str | None
    edge_prob: float | None
    params: dict | None
    env: dict | None


def _check_problem_fields(spec) -> None:
    """Exactly one problem named, an env run's fields with its env, gamma only where the run has none of its own."""
    if spec.env is not None and not spec.env.get("make"):
        raise DgtdInputError(
            f"{', '.join(sorted(spec.env))} set the fields of an env run; name the env too: --env "
            "module.path:make_env (make = ... in the [env] table)"
        )
    given = [name for name in PROBLEM_FIELDS if getattr(spec, name) is not None]
    if len(given) != 1:
        raise DgtdInputError(
            "name exactly one problem: a scenario (e.g. paper-example-1), --problem FILE.npz, "
            "--env module:make_env or --data FILE" + (f" (got {', '.join(given)})" if given else "")
        )
    if spec.gamma is not None and spec.env is None and spec.data is None:
        raise DgtdInputError("gamma is the discount of an --env or --data run; a scenario or problem file has its own")
    if (spec.policies is not None or spec.policies_seed is not None) and spec.problem_file is None:
        raise DgtdInputError(
            "--policies gives the agents of a multi-agent MDP file a learning run's policies: give the file it learnt "
            "on with --problem FILE.npz"
        )
    check_gamma(spec.gamma)


def check_gamma(gamma: float | None) -> None:
    """A discount given for a simulator or recordings: in [0, 1] (NaN refused too)."""
    if gamma is not None and not 0.0 <= gamma <= 1.0:
        raise DgtdInputError(f"gamma must be in [0, 1] (1 only for episodes that end), got {gamma}")


def _from_scenario(spec) -> _Base:
    """A named scenario's problem, network, algorithm and sampling, with the config's edge probability, reward noise
    and restarts."""
    kwargs, params, edge_prob = scenario_arguments(spec.scenario, spec.params or {}, spec.edge_prob)
    _check_task_memory(spec, kwargs)
    sc = scenario_of(spec)
    problem, network = sc.problem, sc.network
    if sc.source is not None:
        _refuse_model_overrides(spec, sc)  # its source sets the links, states and rewards
    if spec.edge_prob is not None and "edge_prob" not in kwargs and spec.graph is None:
        if not hasattr(network, "base"):
            raise DgtdInputError(
                f"scenario {spec.scenario!r} has no random-edge network, so edge_prob does not apply; remove it"
            )
        network, edge_prob = random_edges(network.base, spec.edge_prob), spec.edge_prob
    if spec.reward_noise not in (None, problem.reward_noise):
        problem = with_reward_noise(problem, spec.reward_noise)
    if spec.restarts not in (None, getattr(problem, "restarts", None)):
        problem = with_restarts(problem, spec.restarts)
    # graph None: the scenario's own network, rebuilt from the same parameters
    return _Base(spec, problem, network, sc.algorithm, sc.sampling, sc.iterations, None, edge_prob, params, None)


def _check_task_memory(spec, kwargs: dict) -> None:
    """A generated task of many agents (`dgtd.run.memory.PROBE_FROM`) refused before it is built where it and its
    run's state would not fit in the memory free (`dgtd.run.memory.probed_bytes`: it was killed by the kernel)."""
    from dgtd.run import memory

    n = kwargs.get("n_agents")
    if not isinstance(n, int) or n < memory.PROBE_FROM:
        return

    def make(agents: int):
        return get_scenario(spec.scenario, **{**kwargs, "n_agents": agents})

    try:
        small = make(memory.PROBE_AGENTS[0])
    except DgtdInputError:
        return  # (a task that cannot have so many agents refuses them itself)
    task, defaults = memory.probed_bytes(make, n, small), RunSettings()
    if task is None:
        return
    arcs = 2 * getattr(small.network, "n_edges", 0) * n // memory.PROBE_AGENTS[0]
    state = memory.run_bytes(
        small.algorithm, spec.seeds or defaults.seeds, n, small.problem.n_features, arcs,
        spec.checkpoints or defaults.checkpoints, spec.backend or defaults.backend,
    )  # fmt: skip
    memory.check_task_memory(f"{spec.scenario} with {n:,} agents", task + state, "lower --agents")


def _from_problem_file(spec) -> _Base:
    """A problem file's model, on a ring by default, with DGTD's defaults."""
    policies = None
    if spec.policies is not None:
        from dgtd.problems.io import learned_policies

        policies = learned_policies(spec.policies, check_count("policies_seed", spec.policies_seed or 0, 0))
    problem = load_problem(spec.problem_file, reward_noise=spec.reward_noise or "none", policies=policies)
    if spec.params:
        raise DgtdInputError(
            f"--agents sets the agents of a generated task or a simulator; a problem file's agents are the rows of "
            f"its R ({problem.n_agents} agents): leave out --agents"
            if set(spec.params) == {"agents"}
            else "params are a scenario's parameters, but this run reads a problem file; remove them"
        )
    if spec.restarts is not None:
        problem = with_restarts(problem, spec.restarts)
    return _Base(spec, problem, None, DGTD(), Sampling(), 100_000, "ring", 1.0, None, None)


def _from_env_or_data(spec) -> _Base:
    """A simulator's or a recording's estimated reference and its scenario, linked by positions or a graph."""
    if spec.params:
        raise DgtdInputError("params are a scenario's parameters; an --env run takes its settings in [env]")
    env = None if spec.env is None else asdict(env_spec(spec.env))
    spec = SimpleNamespace(**{**vars(spec), "env": env, "gamma": DEFAULT_GAMMA if spec.gamma is None else spec.gamma})
    sc = scenario_of(spec)
    _refuse_model_overrides(spec, sc, graph_applies=True)
    proximity = env is not None and env["positions"] is not None
    if proximity and (spec.graph is not None or spec.edge_prob is not None):
        raise DgtdInputError(
            "this env links its agents by their positions (env.positions, env.radius); --graph "
            "and --edge-prob do not apply"
        )
    graph, edge_prob = (None, None) if proximity else (spec.graph or "ring", _edge_prob(spec))
    if spec.data is not None:
        _check_recordings(spec, sc)
    return _Base(spec, sc.problem, sc.network, sc.algorithm, sc.sampling, sc.iterations, graph, edge_prob, None, env)


def view(config) -> SimpleNamespace:
    """A config's fields by their flat names, to read (`flat`); a view passes through."""
    return config if isinstance(config, SimpleNamespace) else SimpleNamespace(**flat(config))


def _loss(loss):
    """A loss as recorded: a probability, a list of them (one per agent), or a link file's absolute path."""
    from pathlib import Path

    if loss is None or isinstance(loss, (int, float, list)):
        return float(loss) if isinstance(loss, int) else loss
    try:
        values = [float(x) for x in loss.split(",")]
    except ValueError:
        return str(Path(loss).resolve()) if Path(loss).is_file() else loss  # (`loss_per_arc` says what is wrong)
    return values[0] if len(values) == 1 else values


def channel_for(loss, burst, network, reweight=None, links: dict | None = None):
    """The channel of a run: `dgtd.channels.Perfect`, `dgtd.channels.Lossy` with each arc's loss probability and its
    bursts, or with any of `dgtd.channels.Imperfect`'s ``links`` (delay, wake, bits, top_k, error_feedback) set,
    an `Imperfect` over those links."""
    from dgtd.channels import Arcs, Imperfect, Lossy, Perfect
    from dgtd.channels.imperfect import check_links, wake_per_agent
    from dgtd.channels.lossy import loss_per_arc

    links = {k: v for k, v in (links or {}).items() if v is not None}
    wake = wake_per_agent(links.pop("wake", None), network.n_nodes)
    check_links(links.get("delay", 0), wake, links.get("bits", 64), links.get("top_k"), links.get("error_feedback"))
    imperfect = wake is not None or any(links.get(k) for k in ("delay", "top_k", "error_feedback"))
    imperfect = imperfect or links.get("bits", 64) < 64
    arcs = Arcs.of(network.base.edges, network.n_nodes)
    if loss is None:
        if burst is not None:
            raise DgtdInputError("burst sets how lost messages bunch up; give the loss too (--loss P --burst L)")
        if reweight:
            raise DgtdInputError("reweight corrects for lost messages; give the loss too (--loss P --reweight)")
        if not imperfect:
            return Perfect()
    lossy = Lossy(loss_per_arc(0.0 if loss is None else loss, arcs), burst, bool(reweight))
    if not imperfect:
        return lossy
    return Imperfect(lossy, wake=wake, **{k: v for k, v in links.items() if k != "error_feedback" or v})


LINK_FIELDS = ("delay", "wake", "bits", "top_k", "error_feedback")  # `Imperfect`'s, in [network]


def _links(spec, wake) -> dict:
    return {k: wake if k == "wake" else getattr(spec, k) for k in LINK_FIELDS}


def make_channel(config: RunConfig, network):
    """The channel a resolved config's run uses, over its ``network`` (`resolve`'s)."""
    n = config.network
    return channel_for(n.loss, n.burst, network, n.reweight, {k: getattr(n, k) for k in LINK_FIELDS})


def _edge_prob(spec) -> float:
    return 1.0 if spec.edge_prob is None else spec.edge_prob


def env_spec(table: dict):
    """The `EnvSpec` of an [env] table (or the --env flags), each field checked: unknown ones name the closest."""
    from dgtd.scenarios.user import EnvSpec

    types = field_types(EnvSpec)
    for key in table:
        if key not in types:
            raise DgtdInputError(
                f"unknown field {key!r} in [env]{closest(key, types)} (its fields: {', '.join(types)})"
            )
    values: dict[str, Any] = {k: check_type(f"env.{k}", v, types[k]) for k, v in table.items() if v is not None}
    for key in ("agents", "reference_steps", "reference_groups", "pilot_steps"):
        if values.get(key) is not None and values[key] < (2 if key in ("agents", "reference_groups") else 1):
            raise DgtdInputError(
                f"env.{key} must be at least {2 if key in ('agents', 'reference_groups') else 1}, got {values[key]}"
            )
    if values.get("radius") is not None and values["radius"] <= 0:
        raise DgtdInputError(f"env.radius must be > 0, got {values['radius']}")
    return EnvSpec(**values)


def _plain_env(env: dict | None) -> dict | None:
    """An env table as TOML-ready data: None fields left out, a make given as a file path made absolute."""
    if env is None:
        return None
    from pathlib import Path

    out = {k: _plain(v) for k, v in env.items() if v is not None}
    module, sep, name = out["make"].rpartition(":")
    if module.endswith(".py"):
        out["make"] = f"{Path(module).resolve()}:{name}"
    return out


def _check_recordings(spec, sc) -> None:
    """A run on recordings takes one recording per seed and at most as many steps as they hold."""
    data = sc.data
    seeds = RunSettings.seeds if spec.seeds is None else spec.seeds
    spec = SimpleNamespace(**{**vars(spec), "seeds": seeds})
    if data.recordings is not None and spec.seeds > data.recordings:
        raise DgtdInputError(
            f"{spec.data} holds {data.recordings} recordings, one per seed: run at most --seeds {data.recordings}"
        )
    steps = data.steps(range(spec.seeds))
    if spec.iterations is not None and spec.iterations > steps:
        held = (
            f"the first {spec.seeds} recordings of {spec.data} hold {steps:,} steps each (the shortest)"
            if data.by_seed
            else f"the episodes of {spec.data} hold {steps:,} steps in all"
        )
        raise DgtdInputError(f"{held}: run at most --iterations {steps}")


def _refuse_model_overrides(spec, sc, graph_applies: bool = False) -> None:
    """A scenario with its own sample source sets the links, states and rewards itself: flags that would change
    them could not apply, so they are refused (values equal to the scenario's own, as recorded, are accepted).
    The graph of a user's env or recordings is the run's (``graph_applies``)."""
    own = {
        "--graph": spec.graph if graph_applies else None,
        "--sampling": sc.sampling.mode,
        "--shared": sc.sampling.shared,
        "--reward-noise": sc.problem.reward_noise,
        "--restarts": getattr(sc.problem, "restarts", None),
    }
    given = [
        flag
        for flag, value in (
            ("--graph", spec.graph),
            ("--sampling", spec.sampling),
            ("--shared", spec.shared),
            ("--reward-noise", spec.reward_noise),
            ("--restarts", spec.restarts),
        )
        if value is not None and value != own[flag]
    ]
    if given:
        what = f"scenario {spec.scenario}" if spec.scenario else "an --env or --data run"
        raise DgtdInputError(
            f"{what} simulates its own samples and links; {', '.join(given)} "
            f"{'does' if len(given) == 1 else 'do'} not apply to it (leave {'it' if len(given) == 1 else 'them'} out)"
        )


def scenario_of(config):
    """The `Scenario` of a config (built once per process for the same parameters), or None for a problem file."""
    import json

    spec = view(config)

    if spec.scenario is not None:
        kwargs = scenario_arguments(spec.scenario, spec.params or {}, spec.edge_prob)[0]
        return _scenario(json.dumps({"scenario": spec.scenario, **kwargs}, sort_keys=True))
    if spec.env is not None or spec.data is not None:
        key = {
            "env": asdict(env_spec(spec.env)) if spec.env is not None else None,
            "data": spec.data,
            "gamma": DEFAULT_GAMMA if spec.gamma is None else spec.gamma,
            # as `_scenario` reads them (None: a ring, every link up), so that a config and its resolved copy, which
            # names those defaults, share one scenario and its reference is estimated once
            "graph": spec.graph or "ring",
            "edge_prob": 1.0 if spec.edge_prob is None else spec.edge_prob,
            **{k: getattr(spec, k) for k in SHAPE},
        }
        if spec.data is not None:
            from pathlib import Path

            path = Path(spec.data)
            key["data_stat"] = [path.stat().st_mtime_ns, path.stat().st_size] if path.is_file() else None
        return _scenario(json.dumps(key, sort_keys=True))
    return None


@lru_cache(maxsize=4)
def _scenario(key: str):
    """The scenario a `scenario_of` key describes (its reference, for a simulator, is estimated once)."""
    import json

    from dgtd.scenarios.user import EnvSpec, data_scenario, env_scenario

    d = json.loads(key)
    if "scenario" in d:
        return get_scenario(d.pop("scenario"), **d)

    def network_for(n_agents: int):
        return _network(d["graph"], n_agents, d["edge_prob"], {k: d.get(k) for k in SHAPE})

    if d["env"] is not None:
        return env_scenario(EnvSpec(**d["env"]), d["gamma"], network_for)
    return data_scenario(d["data"], d["gamma"], network_for)


def make_source(config: RunConfig, settings: RunSettings):
    """A fresh sample source for a run of ``spec``, or None when samples come from the model (`ModelSource`).

    Scenarios that simulate a world (e.g. paper-example-2's robots and their proximity links) supply their own;
    pass it as ``run(..., source=make_source(spec, settings))``. Each call starts the same streams again, so
    two algorithms given fresh sources with one seed see identical samples and links.
    """
    sc = scenario_of(config)
    if sc is None or sc.source is None:
        return None
    return sc.source(settings.seed, range(settings.seeds))


def _plain(x):
    return list(x) if isinstance(x, tuple) else x


def scenario_arguments(name: str, params: dict, edge_prob: float | None):
    """(keyword arguments for the scenario's factory, its full parameters less edge_prob, edge_prob used).

    Parameters not given take the factory's defaults, and the resolved config records them all, so that a
    later change of a default does not change what a saved config means.
    """
    from dgtd.scenarios import SCENARIOS

    if name not in SCENARIOS:
        get_scenario(name)  # raises the error that lists the known names
    sig = inspect.signature(SCENARIOS[name])
    names = [p.name for p in sig.parameters.values() if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]
    if "agents" in params and "agents" not in names and "n_agents" in names:  # --agents sizes a generated task
        params = {("n_agents" if k == "agents" else k): v for k, v in params.items()}
    if "n_agents" in params:
        params = {**params, "n_agents": check_count("n_agents", params["n_agents"], 1)}
    for k in params:
        if k == "edge_prob":
            raise DgtdInputError("edge_prob is a field of its own: write it at the top level, not under params")
        if k not in names:
            known = ", ".join(n for n in names if n != "edge_prob") or "none"
            raise DgtdInputError(
                f"scenario {name!r} has no parameter {k!r}{closest(k, names)} (its parameters: {known})"
            )
    kwargs = {p.name: p.default for p in sig.parameters.values() if p.name in names and p.default is not p.empty}
    kwargs.update(params)
    if edge_prob is not None and "edge_prob" in names:
        kwargs["edge_prob"] = edge_prob
    missing = [n for n in names if n not in kwargs]
    if missing:
        raise DgtdInputError(f"scenario {name!r} needs parameter(s) {', '.join(missing)} under params")
    rest = {k: _plain(v) for k, v in kwargs.items() if k != "edge_prob"}
    return kwargs, rest or None, kwargs.get("edge_prob")


def steps_from_the_problem(spec) -> bool:
    """Whether the algorithm's first step comes from the problem (`dgtd.algorithms.mean_dynamics`): on a user's
    problem file, simulator or recording, where no step option is given. Named tasks keep their tuned steps and
    the paper's examples the paper's."""
    given = any(getattr(spec, k) is not None for k in ("alpha0", "beta", "schedule"))
    return any(getattr(spec, k) is not None for k in ("problem_file", "env", "data")) and not given


def problem_start(config):
    """The algorithm a run on a user's problem starts from, before its steps come from the problem: DGTD's defaults
    on a problem file, the scenario's (alpha0 scaled to the features) on a simulator or a recording."""
    spec = view(config)
    return build_algorithm(spec, DGTD() if spec.problem_file is not None else scenario_of(config).algorithm)


def problem_steps(config, problem, network) -> tuple:
    """(the algorithm of a run on a user's problem with its steps from the problem, the header's line saying so or
    ""): `dgtd.algorithms.base.StepSizes.from_the_problem` of `problem_start`; where no step contracts, the
    warning of `dgtd.algorithms.growing_mode` instead."""
    from dgtd.algorithms import growing_mode

    start, moments = problem_start(config), moments_of(problem)
    derived, note = start.from_the_problem(moments, network)
    return derived, growing_mode(start, moments, network) or note


def steps_note(config, problem, network, algorithm) -> str:
    """The header's line on the run's steps: where they come from the problem, which and why (`problem_steps`); on
    a problem file with the user's own steps, a warning where no step would contract (`growing_mode`); else ""."""
    from dgtd.algorithms import growing_mode

    spec = view(config)
    if steps_from_the_problem(spec):
        return problem_steps(config, problem, network)[1]
    if spec.problem_file is not None:
        return growing_mode(algorithm, moments_of(problem), network)
    return ""


def moments_of(problem):
    """The moments the steps are derived from: the model's, or an estimated reference's."""
    estimated = getattr(problem, "moments", None)
    return estimated if estimated is not None else exact_moments(problem)


def exact_moments(problem):
    from dgtd.problems.exact import Moments

    return Moments(problem)


def build_algorithm(spec, default):
    """The config of the algorithm named in ``spec`` (a `view` of a `RunConfig`; default: the scenario's own), with
    the config's fields set on it.

    Another algorithm than the scenario's starts from its own defaults and the scenario's step sizes
    (alpha0, beta, schedule) where it has those fields. A field the algorithm lacks is an error.
    """
    name = spec.algorithm or default.name
    cls = algorithm_class(name)
    own = field_types(cls)
    if isinstance(default, cls):
        algorithm = default
    else:
        algorithm = cls(**{k: getattr(default, k) for k in STEP_SIZE_FIELDS if k in own and hasattr(default, k)})
    over: dict[str, Any] = {}
    for k in ALGORITHM_FIELDS:
        if getattr(spec, k) is not None:
            if k not in own:
                raise DgtdInputError(
                    f"algorithm {name!r} has no parameter {k!r} (its parameters: {', '.join(own)}); remove it"
                )
            over[k] = check_type(f"algorithm.{k}", getattr(spec, k), own[k])
    for k, v in (spec.algorithm_params or {}).items():
        if k not in own:
            raise DgtdInputError(
                f"algorithm {name!r} has no parameter {k!r}{closest(k, own)} (its parameters: {', '.join(own)})"
            )
        over[k] = check_type(f"algorithm.{k}", v, own[k])
    algorithm = replace(algorithm, **over)
    if ":" in name:
        check_users_algorithm(name, algorithm)
    return algorithm


def algorithm_class(name: str):
    """The class ``--algorithm`` names: a registered method, or a user's own (``path/to/file.py:Class`` or
    ``module.path:Class``), a dataclass with the methods of `dgtd.algorithms.base` (README, Adding an algorithm)."""
    from dgtd.algorithms import ALGORITHMS

    if name in ALGORITHMS:
        return ALGORITHMS[name]
    if ":" not in name:
        raise DgtdInputError(
            f"unknown algorithm {name!r}{closest(name, ALGORITHMS)} (known: {', '.join(ALGORITHMS)}; or your own as "
            "path/to/file.py:Class)"
        )
    from dgtd.scenarios.user import load_callable

    cls = load_callable(name, "--algorithm")
    needs = ("init", "sends", "update", "estimate", "name")
    if not (isinstance(cls, type) and is_dataclass(cls) and all(hasattr(cls, k) for k in needs)):
        raise DgtdInputError(
            f"--algorithm {name}: {getattr(cls, '__name__', cls)!s} is not an algorithm class (a frozen dataclass with "
            "init, sends, update and estimate, as dgtd.algorithms.base describes; README, Adding an algorithm)"
        )
    return cls


_CHECKED: set = set()


def check_users_algorithm(name: str, algorithm) -> None:
    """`dgtd.check_algorithm` on the NumPy reference (five small cases, a fraction of a second) before a user's
    algorithm runs, once per configured algorithm and process: its findings are one line each."""
    from dgtd.run.conformance import check_algorithm

    if algorithm in _CHECKED:
        return
    try:
        check_algorithm(algorithm, backends=())
    except AssertionError as e:
        raise DgtdInputError(f"--algorithm {name}: dgtd.check_algorithm found: {e}") from e
    _CHECKED.add(algorithm)


def input_files(config: RunConfig) -> dict:
    """{role: path} of the files a run reads its inputs from (the problem, the recording, the graph's edge list, the
    links' loss), each by its role's name, as ``ROLE_sha256`` in its record."""
    files = {"problem": config.problem.problem_file, "data": config.problem.data}
    if config.problem.policies is not None:  # (a learning run's folder: the file its policies are in)
        given = Path(config.problem.policies)
        files["policies"] = str(given / "policies.npz" if given.is_dir() else given)
    module = (config.algorithm.name or "").rpartition(":")[0]
    files["algorithm"] = module if module.endswith(".py") and Path(module).is_file() else None  # a user's algorithm
    for role in ("graph", "loss"):  # a name or numbers, or a file
        value = getattr(config.network, role)
        files[role] = value if isinstance(value, str) and Path(value).is_file() else None
    return {role: path for role, path in files.items() if path is not None}


def spec_record(config: RunConfig) -> dict:
    """The resolved config as JSON-ready data (`flat`: what summary.json and a checkpoint record), with the SHA-256
    of every file it reads its inputs from (`input_files`), so that a checkpoint is not continued on changed inputs."""
    return flat(config) | {f"{role}_sha256": file_digest(path) for role, path in input_files(config).items()}
