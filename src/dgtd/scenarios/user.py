"""Scenarios from the user's own simulator (``dgtd run --env module:make_env``) or recordings (``--data FILE``).

`EnvSpec` is the ``[env]`` table of an experiment file, field for field; `env_scenario` turns it into a `Scenario`
whose problem is the LSTD reference estimated on independent episodes (`dgtd.sources.env.reference_from_env`) and
whose source steps one copy of the environment per seed. `data_scenario` does the same for a transitions file
(`dgtd.sources.data.TransitionFile`). Neither has a model, so every error is measured against an estimate, and the
run's output says how precise it is.

DGTD's default step size alpha0 = 10 is for features of unit scale (|phi(s)|^2 about 1); here it is divided by
E |phi(s)|^2 measured on the reference's transitions, so that Fourier or tile features of any width work as given,
and kept within what the graph allows (`scaled_dgtd`).
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import inspect
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from dgtd.algorithms.dgtd import DGTD
from dgtd.errors import DgtdInputError, call_user, user_error, user_numbers
from dgtd.fields import option
from dgtd.problems import features as feature_maps
from dgtd.sources.env import random_policy
from dgtd.sources.model import Sampling

FEATURES_HELP = (
    "fourier:ORDER, rbf:CENTRES, tiles:TILINGS:TILES, one-hot, linear, or module:function "
    "(features(states (K, dim)) -> (K, q))"
)
AGENT_PARAMETERS = ("N", "n_agents", "num_agents", "agents")  # how make_env functions name their number of agents
STEP_WORDS = "alpha0 = min(10 / E|phi|^2, sqrt(beta) / lambda_max(L))"
REFERENCE_SEED_OFFSET = 1_000_003  # the reference's streams: seed ids no run uses
ENV_ITERATIONS = 50_000  # an env run's length, unless given


@dataclass(frozen=True)
class EnvSpec:
    """A user's environment, as data (the ``[env]`` table of an experiment file).

    - ``make``: "module.path:function" or "path/to/file.py:function" returning a PettingZoo ParallelEnv or a
      Gymnasium env; "gymnasium:ID" makes a registered Gymnasium env (e.g. "gymnasium:CartPole-v1");
    - ``args``: keyword arguments of that function;
    - ``features``: see `FEATURES_HELP`; the box of fourier, rbf and tiles is the state space's where it is
      finite, else the range of the states seen in ``pilot_steps`` steps;
    - ``policy``: "random" (uniform over discrete actions) or "module:function" (agent, observation, space, rng)
      -> action; or a table of one such per agent ({agent_0 = "...", agent_1 = "random"});
    - ``rewards``: "module:function" (the step's rewards dict) -> (N,) local rewards; default each agent's own;
    - ``agents``: a Gymnasium env's reward is split among this many agents (``split``: "random", or a list of
      shares that sum to 1); a ParallelEnv's function gets it as its N / n_agents / num_agents / agents argument;
    - ``positions`` ("module:function" (env) -> (N, dim)) with ``radius``: agents are linked while within radius of
      each other; without them, the run's --graph and --edge-prob link them;
    - ``reference_steps`` x ``reference_groups``: the transitions of the LSTD reference (each group an independent run).
    """

    make: str | None = field(
        default=None,
        metadata=option(
            "Run on your own simulator: a function returning a PettingZoo ParallelEnv or a Gymnasium env "
            "(module.path:make_env, path/to/file.py:make_env, or gymnasium:ENV-ID). More fields in an experiment "
            "file's [env] table.",
            flags=("--env",),
            metavar="MODULE:FUNCTION",
        ),
    )
    args: dict | None = None  # a table of an experiment file
    features: str = field(
        default="fourier:3", metadata=option(f"The env's linear features: {FEATURES_HELP} (default fourier:3).")
    )
    policy: str | dict = field(
        default="random",
        metadata=option(
            "The env's policy: random, or module:function(agent, observation, space, rng) -> action (default "
            "random; one per agent in the [env] table)."
        ),
    )
    rewards: str | None = field(
        default=None,
        metadata=option(
            "The env's local rewards: module:function(the step's rewards dict) -> (N,) (default: each agent's own).",
            metavar="MODULE:FUNCTION",
        ),
    )
    agents: int | None = field(
        default=None,
        metadata=option(
            "Number of agents: of the scenario (mpe-spread), of your env's function, or the agents a Gymnasium "
            "env's reward is split among."
        ),
    )
    split: str | list | None = field(
        default=None,
        metadata=option(
            "How a Gymnasium env's one reward is split: random (fresh shares at every step, averaging to the "
            "reward; the default) or the agents' shares, e.g. 0.5,0.3,0.2."
        ),
    )
    positions: str | None = field(
        default=None,
        metadata=option(
            "Link the env's agents by their positions: module:function(env) -> (N, dim), with --radius (default: "
            "--graph and --edge-prob link them).",
            metavar="MODULE:FUNCTION",
        ),
    )
    radius: float | None = field(
        default=None, metadata=option("With --positions: agents are linked while within this distance.")
    )
    reference_steps: int = field(
        default=5_000,
        metadata=option("Transitions per group of the env's LSTD reference (default 5000).", metavar="K"),
    )
    reference_groups: int = field(
        default=8,
        metadata=option("Independent groups of the env's LSTD reference, for its standard error (default 8)."),
    )
    pilot_steps: int = field(
        default=2_000,
        metadata=option(
            "Steps an env is run first to find the range of its states, where its space is unbounded (default 2000)."
        ),
    )


def load_callable(text: str, what: str):
    """The object ``module.path:name`` (or ``file.py:name``) names; a one-line error says what is wrong."""
    module_name, sep, attr = str(text).rpartition(":")
    if not sep or not module_name or not attr:
        raise DgtdInputError(f"{what} {text!r} must read module.path:function (or path/to/file.py:function)")
    try:
        if module_name.endswith(".py"):
            module = _module_of_file(Path(module_name), f"{what} {text!r}")
        else:
            module = importlib.import_module(module_name)
    except DgtdInputError:
        raise
    except ImportError as e:
        raise DgtdInputError(
            f"{what} {text!r}: cannot import {module_name} ({e}); install it, or check the name "
            "(a file is written path/to/file.py:function)"
        ) from None
    except Exception as e:  # noqa: BLE001  (the user's module failed while importing)
        raise user_error(f"{what} {text!r}: importing {module_name}", e) from e
    obj = module
    for part in attr.split("."):
        if not hasattr(obj, part):
            if module_name == "gymnasium":
                return partial(_gymnasium_make, attr)
            raise DgtdInputError(f"{what} {text!r}: {module_name} has no {attr}")
        obj = getattr(obj, part)
    if not callable(obj):
        raise DgtdInputError(f"{what} {text!r}: {attr} is not a function")
    return obj


def _module_of_file(path: Path, what: str):
    """The module of a Python file, imported as a script would be (its helper modules beside it import)."""
    if not path.is_file():
        raise DgtdInputError(f"{what}: file {path} does not exist")
    if str(path.parent.resolve()) not in sys.path:
        sys.path.insert(0, str(path.parent.resolve()))
    # one module per file and process, under a name no other module has: registered before it runs, as an import
    # would be (a dataclass defined in it looks its module up), and the same classes however often it is named
    name = f"_dgtd_file_{hashlib.sha1(str(path.resolve()).encode()).hexdigest()[:12]}_{path.stem}"
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise DgtdInputError(f"{what}: file {path} cannot be imported as Python")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module


def _gymnasium_make(env_id: str, **kwargs):
    import gymnasium

    try:
        return gymnasium.make(env_id, **kwargs)
    except gymnasium.error.Error as e:
        raise DgtdInputError(f"gymnasium cannot make {env_id!r}: {e}") from None


def env_name(make: str) -> str:
    """A simulator's name, from its --env: its module's (or file's) last part and its function, as chain.make (a
    factory is often called make: alone it would name nothing), or a Gymnasium env's id."""
    where, _, function = str(make).rpartition(":")
    if not where or where == "gymnasium":
        return function or "env"
    module = Path(where).stem if where.endswith(".py") else where.rpartition(".")[2]
    return f"{module}.{function}"


def env_factory(spec: EnvSpec):
    """(make, probe, label): ``make()`` returns a fresh ParallelEnv (a Gymnasium env wrapped in `SplitReward`);
    ``probe`` is the one made to check it."""
    from dgtd.sources.gym import SplitReward

    if not spec.make:
        raise DgtdInputError("name the environment: --env module.path:make_env (or make = ... in the [env] table)")
    function = load_callable(spec.make, "--env")
    kwargs = dict(spec.args or {})
    params: Mapping[str, inspect.Parameter]
    try:
        params = inspect.signature(function).parameters
    except (TypeError, ValueError):
        params = {}
    named = [p for p in AGENT_PARAMETERS if p in params]
    if spec.agents is not None and named:
        kwargs[named[0]] = int(spec.agents)

    def make_raw():
        return call_user(f"--env {spec.make}: making the environment", function, **kwargs)

    probe = make_raw()
    label = env_name(spec.make)
    if hasattr(probe, "possible_agents"):
        n = len(probe.possible_agents)
        if spec.split is not None:  # it would be ignored, yet written into config.toml as if it held
            raise DgtdInputError(
                f"--split splits a single-agent Gymnasium env's one reward; --env {spec.make} is a PettingZoo "
                "ParallelEnv whose agents have their own rewards: leave out --split (map them with --rewards)"
            )
        if spec.agents is not None and spec.agents != n:
            raise DgtdInputError(
                f"--env {spec.make} made {n} agents, not the {spec.agents} asked for"
                f"{'' if named else ' (it takes no N, n_agents, num_agents or agents argument)'}"
            )
        return make_raw, probe, label
    if hasattr(probe, "step") and hasattr(probe, "observation_space") and not callable(probe.action_space):
        if spec.agents is None:
            raise DgtdInputError(
                f"--env {spec.make} is a single-agent Gymnasium env: give --agents N to split its "
                "reward among N agents (--split random, or shares)"
            )
        return (
            (lambda: SplitReward(make_raw(), spec.agents, spec.split or "random")),
            SplitReward(probe, spec.agents, spec.split or "random"),
            label,
        )
    raise DgtdInputError(
        f"--env {spec.make} returned {type(probe).__name__}, which is neither a PettingZoo ParallelEnv "
        "(possible_agents, reset, step) nor a Gymnasium env; wrap an AEC env with "
        "pettingzoo.utils.aec_to_parallel"
    )


def _state_spaces(env) -> list:
    """The spaces of the state the value function is defined on: the env's state space, a wrapped Gymnasium env's
    observation space, or every agent's observation space (the observations concatenated)."""
    from dgtd.sources.gym import SplitReward

    space = env.env.observation_space if isinstance(env, SplitReward) else getattr(env, "state_space", None)
    return [space] if space is not None else [env.observation_space(a) for a in env.possible_agents]


def _state_box(env) -> tuple[np.ndarray, np.ndarray] | None:
    """The state space's bounds (low, high) where it declares them (inf where it does not), else None."""
    spaces = _state_spaces(env)
    if not all(hasattr(s, "low") for s in spaces):
        return None
    return (
        np.concatenate([np.ravel(s.low) for s in spaces]).astype(np.float64),
        np.concatenate([np.ravel(s.high) for s in spaces]).astype(np.float64),
    )


def _state_words(env) -> str:
    """What the env declares of its state, and what to do for one-hot features, in words."""
    spaces = _state_spaces(env)
    if getattr(env, "state_space", None) is not None or len(spaces) == 1:
        return f"its state space is {spaces[0]}; use linear, fourier, rbf or tiles features for a continuous state"
    kinds = ", ".join(sorted({str(s) for s in spaces}))
    return (
        f"this env declares no state_space, and its {len(spaces)} agents' observation spaces ({kinds}) "
        "concatenated are not one; give the env a state_space (e.g. gymnasium.spaces.Discrete(S) for what its "
        "state() returns), or use linear, fourier, rbf or tiles features"
    )


def _discrete_states(env) -> int | None:
    """The number of states of a discrete state space (one Discrete space), else None."""
    spaces = _state_spaces(env)
    return int(spaces[0].n) if len(spaces) == 1 and hasattr(spaces[0], "n") else None


def policy_of(policy, agents):
    """The callable (agent, observation, space, rng) -> action of a ``policy`` field: "random", "module:function",
    or a table of one of those per agent (every agent named once)."""
    if isinstance(policy, str):
        return policy if policy == "random" else load_callable(policy, "--policy")
    if set(policy) != set(agents):
        missing, unknown = sorted(set(agents) - set(policy)), sorted(set(policy) - set(agents))
        raise DgtdInputError(
            f"the [env] policy table must name every agent once ({', '.join(agents)}); "
            + "; ".join(
                ([f"missing {', '.join(missing)}"] if missing else [])
                + ([f"unknown {', '.join(unknown)}"] if unknown else [])
            )
        )
    own = {a: random_policy if p == "random" else load_callable(p, f"policy.{a}") for a, p in policy.items()}
    return lambda agent, observation, space, rng: own[agent](agent, observation, space, rng)


def build_features(text: str, probe, pilot_states):
    """(features(states) -> (K, q), q, description) for a ``--features`` text; ``pilot_states()`` returns states
    seen under the policy, for a box the state space does not declare."""
    kind, _, rest = str(text).partition(":")
    if kind in ("fourier", "rbf", "tiles"):
        return _box_features(text, kind, rest, probe, pilot_states)
    if kind == "one-hot":
        n = _discrete_states(probe)
        if n is None:
            raise DgtdInputError(f"--features one-hot needs the state to be one Discrete space: {_state_words(probe)}")
        return feature_maps.one_hot(n), n, f"one-hot features of {n} states"
    if kind == "linear":

        def linear(states):
            s = np.asarray(states, dtype=np.float64)
            return np.concatenate([np.ones((len(s), 1)), s], axis=1)

        dim = pilot_states(8).shape[1]
        return linear, dim + 1, f"linear features: 1 and the {dim} state variables"
    if rest:
        function = load_callable(text, "--features")
        states = pilot_states(8)
        what = f"--features {text} on states of shape {states.shape}"
        phi = user_numbers(what, call_user(what, function, states))
        if phi.ndim != 2 or phi.shape[0] != len(states):
            raise DgtdInputError(
                f"--features {text} returned shape {phi.shape} for {len(states)} states; it must return "
                "(K, q): one row of features per state"
            )
        return function, phi.shape[1], f"features {text} ({phi.shape[1]})"
    raise DgtdInputError(f"--features {text!r} is not known: give {FEATURES_HELP}")


def _box_features(text: str, kind: str, rest: str, probe, pilot_states):
    """Fourier, RBF or tile-coding features over the state space's box: its declared bounds where finite and
    reasonable, else the range of the states seen under the policy."""
    try:
        sizes = [int(x) for x in rest.split(":")] if rest else []
    except ValueError:
        sizes = []
    if len(sizes) != (2 if kind == "tiles" else 1) or min(sizes) < 1:
        raise DgtdInputError(
            f"--features {text!r}: write {'tiles:TILINGS:TILES' if kind == 'tiles' else kind + ':N'} "
            "with positive integers"
        )
    states, declared = None, _state_box(probe)
    if declared is not None and len(declared[0]) != pilot_states(8).shape[1]:  # state() is not the observations
        declared = None
    low, high = declared if declared is not None else (np.zeros(0), np.zeros(0))
    keep = np.isfinite(low) & np.isfinite(high) & (high - low < 1e6)
    if declared is None or not keep.all():  # the range seen, where no finite and reasonable bound is declared
        states = pilot_states()
        seen_low, seen_high = states.min(axis=0), states.max(axis=0)
        if declared is not None:
            seen_low, seen_high = np.where(keep, low, seen_low), np.where(keep, high, seen_high)
        low, high = seen_low, np.where(seen_high > seen_low, seen_high, seen_low + 1.0)
    dim = len(low)
    n = {"fourier": (sizes[0] + 1) ** dim, "rbf": 1 + sizes[0] ** dim, "tiles": sizes[0] * (sizes[-1] + 1) ** dim}[kind]
    if n > 4096:
        raise DgtdInputError(
            f"--features {text} on a {dim}-dimensional state makes {n:,} features; lower it, or "
            "give your own features (module:function)"
        )
    f = {
        "fourier": lambda: feature_maps.fourier(sizes[0], low, high),
        "rbf": lambda: feature_maps.rbf(sizes[0], low, high),
        "tiles": lambda: feature_maps.tile_coding(sizes[0], sizes[1], low, high),
    }[kind]()
    where = "the state space's bounds" if states is None else f"the range of {len(states):,} states seen"
    return f, n, f"{kind} features ({n}) over {where}"


def mean_proximity_network(proximity, frequency):
    """The mean graph of a proximity network (for mu* and the connectivity check): each pair of agents linked with
    the frequency they were within radius in the reference episodes; a pair that never met is a one-line error."""
    from dgtd.graphs.random import random_edges

    if np.any(frequency <= 0):
        raise DgtdInputError(
            f"within radius {proximity.radius:g} some pairs of agents never met in the reference "
            "episodes; raise the radius"
        )
    return random_edges(proximity.base, frequency)


def graph_step_cap(base_graph) -> float:
    """The largest alpha0 the graph allows DGTD without projection boxes: sqrt(beta) / lambda_max(L) of the graph
    with every link up. Without a model there are no boxes (section 7's Lemma 2 needs the model), and a first step
    alpha_1 above about 1.2 / lambda_max(L) makes the consensus part of the update expand: the ring of 4 agents
    (lambda_max = 4) diverges at DGTD's default alpha_1 = 0.32."""
    lam = float(np.linalg.eigvalsh(base_graph.laplacian()).max())
    return float(np.sqrt(DGTD().beta) / lam) if lam > 0 else float("inf")


def feature_scale(moments) -> float:
    """E |phi(s)|^2 (the trace of the moments' M), or 1 where it is smaller: what unit-scale step sizes divide by."""
    return max(float(np.trace(moments.M)), 1.0)


def compare_steps(moments) -> dict:
    """The algorithms' alpha0 in `dgtd compare` on a user's problem: garnet's (features of unit scale, as DGTD's
    default) divided by `feature_scale`, as DGTD's is; ``--tune`` picks them on separate seeds instead."""
    from dgtd.scenarios.tuned import tuned_steps

    scale = feature_scale(moments)
    return {
        name: {"alpha0": fields["alpha0"] / scale}
        for name, fields in tuned_steps("garnet").items()
        if "alpha0" in fields
    }


def compare_note(moments) -> str:
    """Where `compare_steps` come from, in words."""
    return f"garnet's tuned steps divided by the features' scale E|phi|^2 = {feature_scale(moments):.3g}"


def scaled_dgtd(reference, base_graph) -> DGTD:
    """DGTD with its default alpha0 divided by `feature_scale`, and at most `graph_step_cap`."""
    return DGTD(alpha0=min(DGTD().alpha0 / feature_scale(reference.moments), graph_step_cap(base_graph)))


def problem_compare_steps(moments, network, start, derive: bool) -> tuple[dict, str]:
    """({algorithm: fields}, where they come from, in words) of `dgtd compare` on a user's problem file, simulator
    or recording (``moments`` the model's, or the estimated reference's): garnet's
    tuned alpha0 divided by `feature_scale` (the late steps, as `compare_steps`) on the schedule and offset of
    ``start`` (the algorithm the run starts from: DGTD's defaults, or the step options given); with ``derive`` (no
    step option given) each method's first step at most what its own mean dynamics allow, the rule `dgtd run`
    takes (`dgtd.algorithms.mean_dynamics`), its offset raised to meet it."""
    from dgtd.algorithms import make_algorithm

    settings, none = {}, []
    for name, fields in compare_steps(moments).items():
        algorithm = make_algorithm(name, alpha0=fields["alpha0"], beta=start.beta, schedule=start.schedule)
        if derive:
            derived, note = algorithm.from_the_problem(moments, network)
            if note and derived is algorithm:  # no step contracts its mean dynamics, or they are too large
                none.append(name)
            algorithm = derived
        settings[name] = {"alpha0": algorithm.alpha0, "beta": algorithm.beta}
    note = compare_note(moments)
    if derive:
        note += (
            "; every first step at most what the method's mean dynamics allow (half the largest step at which "
            "every mode contracts, and 1 / max |phi(s)|^2), its offset raised to meet it, as dgtd run does"
        )
    if none:
        note += (
            f"; no first step comes from the mean dynamics of {', '.join(none)} here (none contracts them, or they "
            "are too large to analyse): their steps are kept"
        )
    return settings, note


def problem_scenario(problem, network, algorithm, sampling, iterations: int, start=None):
    """The `Scenario` of a user's problem file (`dgtd compare --problem`): the run's network, algorithm and length,
    and every algorithm compared at `problem_compare_steps` from ``start`` (the algorithm before its steps came
    from the problem; None: they did not)."""
    from dgtd.problems.exact import Moments
    from dgtd.scenarios.base import Scenario

    settings, note = problem_compare_steps(Moments(problem), network, start or algorithm, start is not None)
    return Scenario(
        problem=problem,
        network=network,
        algorithm=algorithm,
        sampling=sampling,
        iterations=iterations,
        description=f"problem file {problem.name}",
        compare_settings=settings,
        compare_note=note,
    )


def env_scenario(spec: EnvSpec, gamma: float, network_for):
    """The `Scenario` of a user's environment; ``network_for(N)`` is the run's graph over N agents."""
    from dgtd.graphs.proximity import ProximityNetwork
    from dgtd.scenarios.base import Scenario
    from dgtd.sources.env import EnvSource, reference_from_env
    from dgtd.sources.gym import SplitReward

    make, probe, label = env_factory(spec)
    N = len(probe.possible_agents)
    policy = policy_of(spec.policy, probe.possible_agents)
    reward_map = None if spec.rewards is None else load_callable(spec.rewards, "rewards")
    if (spec.positions is None) != (spec.radius is None):
        raise DgtdInputError(
            "positions and radius go together: positions = 'module:function' (env) -> (N, dim) "
            "and the radius within which agents talk"
        )
    if spec.positions is not None:
        radius = float(spec.radius) if spec.radius is not None else 0.0  # (checked above: given with positions)
        links: dict[str, Any] = dict(positions=load_callable(spec.positions, "positions"))
        links["proximity"] = ProximityNetwork(N, radius)
        network = None
    else:
        network = network_for(N)
        links = dict(network=network)

    def source(features, seed, seed_ids, offset=0, width=None):
        return EnvSource(
            make,
            features,
            seed,
            seed_ids,
            policy=policy,
            seed_offset=offset,
            n_features=width,
            reward_map=reward_map,
            name=env_name(str(spec.make)),
            **links,
        )

    def pilot_states(steps=None):
        return _pilot(source(_as_numbers, 0, [0], REFERENCE_SEED_OFFSET - 1), spec, steps)

    features, q, about = build_features(spec.features, probe, pilot_states)
    reference, frequency = reference_from_env(
        lambda g: source(features, 0, [g], REFERENCE_SEED_OFFSET, q),
        q,
        gamma,
        label,
        steps=spec.reference_steps,
        groups=spec.reference_groups,
    )
    if network is None:
        network = mean_proximity_network(links["proximity"], frequency)
    algorithm = scaled_dgtd(reference, network.base)
    kind = "Gymnasium" if isinstance(probe, SplitReward) else "PettingZoo"
    return Scenario(
        problem=reference,
        network=network,
        algorithm=algorithm,
        sampling=Sampling(mode="markov", shared=True),
        iterations=ENV_ITERATIONS,
        description=f"{kind} env {spec.make}, {N} agents, {about}, policy "
        f"{spec.policy if isinstance(spec.policy, str) else 'one per agent'}; {STEP_WORDS} = "
        f"{algorithm.alpha0:.4g}",
        source=lambda seed, seed_ids: source(features, seed, seed_ids, width=q),
        report=TrajectoryReport(lambda: source(features, 0, [0], TRAJECTORY_SEED_OFFSET, q)),
        compare_settings=compare_steps(reference.moments),
        compare_note=compare_note(reference.moments),
    )


def _as_numbers(states) -> np.ndarray:
    return np.asarray(states, dtype=np.float64)


def _pilot(src, spec: EnvSpec, steps=None) -> np.ndarray:
    """The states of a pilot run of ``src`` (at most ``spec.pilot_steps``): what box features are fitted to."""
    src.start()
    states = src.next_block(min(steps or spec.pilot_steps, spec.pilot_steps)).table.phi
    if not np.isfinite(states).all():
        raise DgtdInputError(f"--env {spec.make}: the environment's states hold NaN or infinite values")
    return states


def learning_env(spec: EnvSpec, gamma: float, network_for):
    """(`dgtd.sources.team_env.EnvTask`, network, what the features are) of a user's environment for learners (`dgtd
    learn --env`): its factory, the critics' features (`build_features`, fitted where need be to a pilot run under
    uniform actions, on streams of their own), its rewards mapped where ``spec.rewards`` says; linked by the run's
    graph (``network_for(N)``): positions are `dgtd run`'s."""
    from dgtd.sources.env import EnvSource
    from dgtd.sources.team_env import EnvTask, discrete_actions

    if spec.positions is not None or spec.radius is not None:
        raise DgtdInputError(
            "learners are linked by --graph and --edge-prob; --positions and --radius link `dgtd run`'s agents"
        )
    make, probe, label = env_factory(spec)
    N = len(probe.possible_agents)
    if N == 0:  # (it was said as "a graph needs at least one node")
        raise DgtdInputError(f"{env_name(str(spec.make))} has no agents (its possible_agents is empty): nothing learns")
    discrete_actions({a: probe.action_space(a) for a in probe.possible_agents}, env_name(str(spec.make)))
    network = network_for(N)
    reward_map = None if spec.rewards is None else load_callable(spec.rewards, "rewards")

    def pilot_states(steps=None):
        src = EnvSource(
            make, _as_numbers, 0, [0], network=network, reward_map=reward_map,
            seed_offset=REFERENCE_SEED_OFFSET - 1, name=env_name(str(spec.make)),
        )  # fmt: skip
        return _pilot(src, spec, steps)

    features, _, about = build_features(spec.features, probe, pilot_states)
    return EnvTask(make, features, gamma, label, N, reward_map), network, about


def data_scenario(path: str, gamma: float, network_for):
    """The `Scenario` of a transitions file (its `TransitionFile` as ``data``): recording k is seed k (or each seed
    replays every episode in an order of its own), the reference LSTD over all of it."""
    from dgtd.scenarios.base import Scenario
    from dgtd.sources.data import DataSource, TransitionFile

    data = TransitionFile(path)
    reference = data.reference(gamma, name=Path(path).stem)
    network = network_for(data.N)
    algorithm = scaled_dgtd(reference, network.base)
    return Scenario(
        problem=reference,
        network=network,
        algorithm=algorithm,
        sampling=Sampling(mode="markov"),
        iterations=data.steps(range(data.recordings or 1)),
        description=f"recorded transitions {path}: "
        f"{data.recordings if data.by_seed else len(data.units):,} "
        f"{'recordings' if data.by_seed else 'episodes'} of {data.N} agents, {int(data.offsets[-1]):,} "
        f"steps in all{'' if data.by_seed else ', replayed by each seed in an order of its own'}; "
        f"{STEP_WORDS} = {algorithm.alpha0:.4g}",
        source=lambda seed, seed_ids: DataSource(data, seed_ids, seed, network),
        data=data,
        compare_settings=compare_steps(reference.moments),
        compare_note=compare_note(reference.moments),
    )


TRAJECTORY_SEED_OFFSET = 2_000_003  # the report's trajectory: streams neither the run nor the reference uses


@dataclass(eq=False)
class TrajectoryReport:
    """After a run on an environment: every agent's value estimate phi(s)' w_i (seed 0, tail average) along a fresh
    trajectory of ``steps`` steps under the same policy, beside the reference's phi(s)' w*; figure ``values.png``
    (`dgtd.plots.values`). Called as ``report(result, source) -> (dict, text)``."""

    make_source: Callable[[], Any]  # () -> a fresh one-copy source on streams of their own
    steps: int = 200
    _states: tuple | None = None  # (features of the states visited (T, q), restarts): drawn once, for every run

    def trajectory(self, result) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(reference values (T,), the result's agents' values (N, T), the steps at which an episode restarted)."""
        if self._states is None:
            source = self.make_source()
            source.start()
            blk = source.next_block(self.steps)
            phi = blk.table.phi
            s, s_next = blk.s[:, 0, 0], blk.s_next[:, 0, 0]
            self._states = (phi[s], 1 + np.flatnonzero(np.any(phi[s[1:]] != phi[s_next[:-1]], axis=1)))
        phi, restarts = self._states
        return phi @ result.w_star, result.w_tail[0] @ phi.T, restarts

    def __call__(self, result, source) -> tuple[dict, str]:
        ref, agents, restarts = self.trajectory(result)
        scale = max(float(np.sqrt(np.mean(ref**2))), 1e-300)
        err = np.sqrt(np.mean((agents - ref) ** 2, axis=1)) / scale
        numbers = {
            "trajectory_steps": self.steps,
            "trajectory_episodes": len(restarts) + 1,
            "trajectory_value_error": err.tolist(),
        }
        text = (
            f"along a fresh trajectory of {self.steps} steps ({len(restarts) + 1} episode(s)), the agents' values "
            f"(tail-averaged, seed 0) are within {err.max():.2%} (RMS, relative) of the reference's"
        )
        return numbers, text
