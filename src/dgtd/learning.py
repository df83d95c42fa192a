"""`dgtd learn`'s configuration: the task the agents learn on, the actors, and what the command shares with `dgtd
run` (the critic by `--algorithm` and its steps, the network and its links, the run's length and seeds), each option
made from its field as `dgtd run`'s are, checked here in one place.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from types import SimpleNamespace

from dgtd.errors import DgtdInputError
from dgtd.fields import option

ITERATIONS = 20_000  # a learning run's steps (-T) where not given
CRITIC_STEPS = {"alpha0": 1.0, "beta": 100.0}  # the critics' default steps here: features of unit scale, tabular
ACTOR_STEP = {"state": 0.5, "action": 0.1}  # the actors' first step by what the critics evaluate (measured, pull-away)


@dataclass(frozen=True)
class LearnConfig:
    """The learning fields of `dgtd learn` (the others are `dgtd.config.RunConfig`'s, by their flat names)."""

    agents: int | None = field(default=None, metadata=option("Agents of the task (default: the task's, 4)."))
    states: int | None = field(default=None, metadata=option("States of the task (default: the task's, 3)."))
    actor: str = field(
        default="networked",
        metadata=option(
            "networked: Zhang et al.'s actor-critic with the chosen critic and a consensus estimate of the team's "
            "reward; independent: each agent its own reward, sending nothing; centralised: every agent the team's "
            "reward, a ceiling no network gives."
        ),
    )
    actor_step: float | None = field(
        default=None,
        metadata=option(
            "The actor's steps step / (1 + k / offset)^power: step (default 0.5; 0.1 with --values action, whose "
            "critic's first steps favour the actions sampled most and need the slower actor; 0.002 in mpe-spread)."
        ),
    )
    actor_offset: float | None = field(
        default=None, metadata=option("The actor's steps: offset (default 1000; 10000 in mpe-spread).")
    )
    actor_power: float = field(
        default=0.8, metadata=option("The actor's steps: power, in (1/2, 1] so that the critic is the faster.")
    )
    entropy: float = field(
        default=0.0,
        metadata=option(
            "The actors' entropy bonus tau: each ascends J + tau H(pi_i(. | s)), its advantage less tau log pi_i(a_i "
            "| s) (0: none; J is reported without it)."
        ),
    )
    actor_warmup: int | None = field(
        default=None,
        metadata=option(
            "Steps for which the actors hold still while the critics learn the starting policies' values (default: "
            "2000, at most a tenth of the run)."
        ),
    )
    values: str | None = field(
        default=None,
        metadata=option(
            "What the critics evaluate: state (values V and a consensus estimate of the team's reward, Zhang et al.'s "
            "Algorithm 2; the default) or action (values Q on additive features of the state and joint action, their "
            "Algorithm 1)."
        ),
    )
    objective: str = field(
        default="average",
        metadata=option(
            "What the actors ascend and J, J* measure: average, the long-run average team reward (differential "
            "critics, Zhang et al.'s Algorithm 2), or discounted, the normalised discounted return from the start "
            "(critics discounted by the task's gamma, or --gamma in a simulator)."
        ),
    )
    team_reward: str | None = field(
        default=None,
        metadata=option(
            "How networked agents estimate the team's reward in their advantage: regression, Zhang et al.'s (each "
            "agent N S A numbers mixed over the links: O(N^2) a step in all; the default), or neighbourhood, each "
            "agent's estimate of its neighbours' and its own rewards given its own action (one number over each link "
            "a step; exact where an agent's action moves only its neighbours' rewards)."
        ),
    )
    scheme: str | None = field(
        default=None,
        metadata=option(
            "zhang: Zhang et al.'s actor-critic, a step at a time or in --batch rounds (the default); chen: Chen, "
            "Zhou, Chen and Zou's Algorithm 1 (ICML 2022): each iteration a critic of --critic-batches mini-batches of "
            "--critic-batch samples and --critic-rounds consensus rounds, then --batch actor samples from the "
            "discounted visitation chain, their rewards mixed by --reward-rounds rounds; -T counts samples; a fixed "
            "graph, the discounted objective (docs/control.md)."
        ),
    )
    critic_batches: int | None = field(
        default=None, metadata=option("--scheme chen: the critic's mini-batches an iteration, T_c (default 50).")
    )
    critic_batch: int | None = field(
        default=None, metadata=option("--scheme chen: samples of a critic's mini-batch, N_c (default 10).")
    )
    critic_rounds: int | None = field(
        default=None,
        metadata=option("--scheme chen: consensus rounds after the critic's mini-batches, T_c' (default 10)."),
    )
    reward_rounds: int | None = field(
        default=None,
        metadata=option("--scheme chen: consensus rounds on each sampled reward, T_r (default 5)."),
    )
    start_from: str | None = field(
        default=None,
        metadata=option(
            "A learning run's folder (or its policies.npz) on the same task: the actors start from the policies it "
            "ended with (each probability at least 1e-6), not the task's.",
            flags=("--from",),
            metavar="DIR",
        ),
    )
    from_seed: int | None = field(
        default=None, metadata=option("Which seed's policies --from takes (default 0).", metavar="K")
    )
    batch: int | None = field(
        default=None,
        metadata=option(
            "Steps of a round (Zhang et al.'s Algorithm 2 in mini-batches, the baseline of Chen et al.'s paper): the "
            "agents communicate and move once a round, by the mean of its samples (default 1); with --scheme chen, "
            "the actor's samples an iteration, N (default 2000).",
            metavar="M",
        ),
    )


SHARED = (
    "problem_file", "algorithm", "alpha0", "beta", "schedule", "graph", "edge_prob", "mean_degree", "rewire",
    "graph_seed", "env_make", "features", "rewards", "split", "gamma", "pilot_steps", "loss", "burst", "reweight",
    "delay", "wake", "bits", "top_k", "error_feedback", "iterations", "seeds", "seed", "checkpoints", "backend",
)  # fmt: skip
"""The options `dgtd learn` shares with `dgtd run`."""


def resolve_learning(task: str | None, values: dict) -> SimpleNamespace:
    """The pieces of a learning run from the command's option values (flat names, None where not given): the team MDP,
    the network, the channel, the critic, the actor and the settings, and the record of what was asked."""
    from dgtd.algorithms import make_algorithm
    from dgtd.algorithms.actor import SoftmaxActor
    from dgtd.config import SHAPE, _network, build_algorithm, channel_for
    from dgtd.problems.team import TASKS
    from dgtd.run.learn import LearnSettings

    own = {f.name: values.get(f.name) for f in fields(LearnConfig)}
    file = values.get("problem_file")
    if [task is not None, file is not None, values.get("env_make") is not None].count(True) != 1:
        raise DgtdInputError(
            f"name one learning task ({', '.join([*TASKS, *ENV_TASKS])}), --problem FILE.npz or --env "
            f"module:make_env; got {task!r}" + ("" if file is None else f" and --problem {file}")
        )
    mdp, env = None, None
    shape = {k: values.get(k) for k in SHAPE}

    def network_for(n: int):
        return _network(values.get("graph") or "ring", n, _given(values, "edge_prob", 1.0), shape)

    if values.get("env_make") is not None or task in ENV_TASKS:
        env, network = _env_task(task, own, values, network_for)
        n_agents, defaults, actor_defaults = env.n_agents, ENV_CRITIC_STEPS, ENV_ACTOR_STEPS
    else:
        mdp = _team_mdp(task, file, own, _given(values, "seeds", 2))
        if values.get("gamma") is not None:  # (it was run at the task's own and recorded as the one given)
            raise DgtdInputError(
                f"gamma is the discount of a simulator (--env, {', '.join(ENV_TASKS)}); "
                f"{task or file} has its own ({mdp.gamma:g})"
            )
        n_agents, defaults = mdp.n_agents, CRITIC_STEPS
        actor_defaults = {"step": ACTOR_STEP[_given(own, "values", "state")], "offset": 1000.0}
        network = network_for(n_agents)
    links = {k: values.get(k) for k in ("delay", "wake", "bits", "top_k", "error_feedback")}
    channel = channel_for(values.get("loss"), values.get("burst"), network, values.get("reweight"), links)
    spec = SimpleNamespace(
        algorithm=values.get("algorithm"),
        algorithm_params=None,
        **{k: values.get(k) for k in ("alpha0", "beta", "schedule", "kappa", "rho")},
    )
    critic = build_algorithm(spec, make_algorithm("dgtd", **defaults))
    from dgtd.run.learn import distributed_critic

    distributed_critic(critic)  # (refused before the header, in one line)
    actor = SoftmaxActor(
        _given(own, "actor_step", actor_defaults["step"]),
        _given(own, "actor_offset", actor_defaults["offset"]),
        _given(own, "actor_power", 0.8),
        own["actor_warmup"],
        _given(own, "entropy", 0.0),
    )
    settings = LearnSettings(
        iterations=_given(values, "iterations", ITERATIONS),
        seeds=_given(values, "seeds", 2),
        seed=_given(values, "seed", 0),
        checkpoints=_given(values, "checkpoints", 40),
        actor=_given(own, "actor", "networked"),
        batch=_given(own, "batch", 1) if own["scheme"] != "chen" else 1,  # (chen: its actor's batch, `ChenSteps`)
        values=_given(own, "values", "state"),
        objective=_given(own, "objective", "average"),
        team_reward=_given(own, "team_reward", "regression"),
        backend=_given(values, "backend", "numba" if env is None else "numpy"),
    )
    settings, chen = _scheme(own, values, settings, channel, env)
    if settings.backend == "jax" and env is None and chen is None:
        from dgtd.backends import jax as on_jax

        on_jax.check_supported(channel)  # (JAX missing, or links it does not run: before the header, in one line)
    record = {"task": task, **{k: v for k, v in {**values, **own}.items() if v is not None}}
    if file is not None:
        from dgtd.problems.io import file_digest

        record["problem_sha256"] = file_digest(file)
    return SimpleNamespace(
        mdp=mdp, env=env, network=network, channel=channel, critic=critic, actor=actor, settings=settings,
        record=record, chen=chen,
    )  # fmt: skip


def _scheme(own: dict, values: dict, settings, channel, env) -> tuple:
    """(the settings, Chen et al.'s `ChenSteps` where --scheme chen, else None), once the team-reward estimate and
    the scheme asked are found able to run with the rest (one line where not)."""
    from dgtd.run.learn import neighbourhood_links

    if own["team_reward"] is not None and (settings.actor != "networked" or settings.values != "state"):
        raise DgtdInputError(
            f"--team-reward is how networked agents with state-value critics estimate the team's reward; "
            f"{settings.actor} actors" + (" with --values action" if settings.values != "state" else "") + " keep none"
        )
    if settings.team_reward == "neighbourhood":
        neighbourhood_links(channel)
    if _given(own, "scheme", "zhang") != "chen":
        sizes = [f"--{k.replace('_', '-')}" for k in CHEN_SIZES if own[k] is not None]
        if sizes:  # (they were ignored)
            raise DgtdInputError(f"{', '.join(sizes)} size Chen et al.'s Algorithm 1: give --scheme chen")
        return settings, None
    return replace(settings, objective="discounted"), _chen_steps(own, values, env)


CHEN_SIZES = ("critic_batches", "critic_batch", "critic_rounds", "reward_rounds")  # Algorithm 1's own options
CHEN_FIXED = (
    "algorithm", "schedule", "beta", "values", "team_reward", "entropy", "actor_warmup", "actor_offset",
    "actor_power", "loss", "burst", "reweight", "delay", "wake", "bits", "top_k", "error_feedback",
)  # fmt: skip
"""What Chen et al.'s Algorithm 1 fixes itself: its critic, its steps' form, perfect links (--alpha0 is its beta)."""


def _chen_steps(own: dict, values: dict, env):
    """`dgtd.run.chen.ChenSteps` from the options, each not given its default (the actor's step alpha N / 10, as
    their three runs had it; the critic's beta --alpha0, 0.5), and what it cannot take refused in one line."""
    from dgtd.run.chen import ChenSteps

    given = [name for name in CHEN_FIXED if {**values, **own}.get(name) is not None]
    if env is not None or given or _given(own, "actor", "networked") != "networked":
        what = "a simulator" if env is not None else ", ".join(f"--{n.replace('_', '-')}" for n in given)
        raise DgtdInputError(
            f"--scheme chen is Chen et al.'s networked Algorithm 1 on a model, with its own critic, steps and "
            f"perfect links: not {what or '--actor ' + str(own['actor'])}"
        )
    if own["objective"] == "average":
        raise DgtdInputError("--scheme chen ascends the discounted return (their J): leave out --objective average")
    batch = _given(own, "batch", 2000)
    sizes = {k: own[k] for k in CHEN_SIZES if own[k] is not None}
    return ChenSteps(
        batch, **sizes, actor_step=_given(own, "actor_step", batch / 10), critic_step=_given(values, "alpha0", 0.5)
    )


def _team_mdp(task: str | None, file, own: dict, seeds: int):
    """The team MDP of a named task or a problem file (a task of many agents refused first where it and ``seeds``
    seeds of its learners would not fit in memory: `_check_memory`)."""
    from dgtd.problems.team import TASKS

    if file is not None:
        from dgtd.problems.io import load_team_mdp

        if own["agents"] is not None or own["states"] is not None:
            raise DgtdInputError("--agents and --states size a named task; a problem file's sizes are its arrays'")
        mdp = load_team_mdp(file)
    elif task not in TASKS:
        from dgtd.run.networked import TASKS as NETWORKED

        if task in NETWORKED:  # (agents with local states: their own command)
            raise DgtdInputError(f"{task} is a networked system, agents with local states: `dgtd networked {task}`")
        raise DgtdInputError(f"name a learning task: {', '.join([*TASKS, *ENV_TASKS])}; got {task!r}")
    else:
        sizes = {k: v for k, v in (("n_agents", own["agents"]), ("n_states", own["states"])) if v is not None}
        _check_memory(task, sizes, own, seeds)
        mdp = TASKS[task](**sizes)
    if own["start_from"] is not None:
        mdp = _started_from(mdp, own["start_from"], own["from_seed"] or 0)
    elif own["from_seed"] is not None:
        raise DgtdInputError("--from-seed picks the seed of a --from DIR: give the learning run's folder")
    return mdp


def _started_from(mdp, path: str, seed: int):
    """The team MDP with a learning run's last policies (`dgtd.problems.io.learned_policies`) as its starting ones,
    each of the agent's shape (S, A_i)."""
    from dataclasses import replace

    from dgtd.problems.io import learned_policies
    from dgtd.run.settings import check_count

    policies = learned_policies(path, check_count("from_seed", seed, 0))
    shapes = [(mdp.n_states, n) for n in mdp.actions]
    if [p.shape for p in policies] != shapes:
        raise DgtdInputError(
            f"--from {path}: its policies are of {len(policies)} agents, {policies[0].shape[0]} states and "
            f"{policies[0].shape[1]} actions; {mdp.name} has {mdp.n_agents} agents, {mdp.n_states} states and "
            f"{max(mdp.actions)} actions: a run on another task"
        )
    return replace(mdp, policies=tuple(policies))


def _check_memory(task: str, sizes: dict, own: dict, seeds: int) -> None:
    """Refuse before it is built a named task sized by --agents whose team MDP (`dgtd.run.memory.probed_bytes`, from
    `dgtd.run.memory.PROBE_FROM` agents) and learners would not fit in the memory free: per seed and agent its actor
    (S A numbers), its critic (about 8 q), and networked, its estimate of the team's reward over the additive
    features (N S A: O(N^2) in all), or with action values its critic's N S A weights (it ended in numpy's "Unable
    to allocate 14.2 PiB" after 21 s at 24 GB)."""
    from dgtd.problems.team import TASKS
    from dgtd.run import memory

    n = sizes.get("n_agents")
    if n is None or n < memory.PROBE_AGENTS[0]:
        return

    def make(agents: int):
        return TASKS[task](**{**sizes, "n_agents": agents})

    try:
        small = make(memory.PROBE_AGENTS[0])
    except DgtdInputError:
        return  # (a task with a joint table refuses so many agents itself)
    S, A, q = small.n_states, max(small.actions), small.n_features
    networked, action_values = _given(own, "actor", "networked") == "networked", own["values"] == "action"
    estimate = 0 if not networked or action_values else n * S * A  # Zhang et al.'s regression: N S A an agent
    if own["team_reward"] == "neighbourhood":
        estimate = 8 * S * A  # a slot of S A numbers for itself and each neighbour, a sparse graph's few
    per_agent = S * A + 8 * q + estimate + 8 * n * S * A * action_values
    task_bytes = memory.probed_bytes(make, n, small) if n >= memory.PROBE_FROM else 0
    lower = "lower --agents"
    if networked and own["team_reward"] != "neighbourhood":
        lower += (
            "; --team-reward neighbourhood keeps an estimate of the degree's size, not the team's; --actor "
            "centralised or independent keep none"
        )
    memory.check_task_memory(
        f"{task} with {n:,} agents and {seeds} seed(s) of {_given(own, 'actor', 'networked')} learners",
        (task_bytes or 0) + memory.BYTES * seeds * n * per_agent,
        lower,
    )


ENV_TASKS = {"mpe-spread": "MPE2's simple_spread (cooperative navigation), --agents particles (3)"}
ENV_CRITIC_STEPS = {"alpha0": 0.1, "beta": 100.0}  # the critics' steps on spread's features (|phi|^2 about 10)
# linear softmax actors on 19 observation features: at 0.02 the policies collapse within 10 000 steps (measured)
ENV_ACTOR_STEPS = {"step": 0.002, "offset": 10_000.0}


ENV_FIELDS = ("features", "rewards", "split", "pilot_steps")  # what `dgtd learn --env` reads of `EnvSpec`


def _env_task(task: str | None, own: dict, values: dict, network_for) -> tuple:
    """(a simulator to learn in, `dgtd.sources.team_env.EnvTask`; its network): a named one sized by --agents, or a
    user's (--env module:make_env, its --features)."""
    from functools import partial

    from dgtd.config import check_gamma
    from dgtd.scenarios.mpe import make_spread, spread_features
    from dgtd.sources.team_env import EnvTask

    name = task or values["env_make"]
    check_gamma(values.get("gamma"))
    if values.get("gamma") is not None and _given(own, "objective", "average") == "average":  # (recorded, unused)
        raise DgtdInputError(
            "gamma discounts the critics of the discounted objective; under --objective average (the default) they "
            "are differential: give --objective discounted with --gamma"
        )
    if own["start_from"] is not None or own["from_seed"] is not None:
        raise DgtdInputError(
            f"--from starts a team MDP's tabular actors from a learning run's policies; {name}'s actors are linear in "
            "its observations"
        )
    if own["states"] is not None or own["values"] not in (None, "state") or own["batch"] not in (None, 1):
        raise DgtdInputError(
            f"{name} is a simulator: its states are its own, and its critics evaluate state values a step at a time "
            "(no --states, --values action or --batch)"
        )
    if task is not None and values.get("env_make") is not None:
        raise DgtdInputError(f"name one simulator: the task {task} or --env {values['env_make']}, not both")
    if task is None:
        from dgtd.config import env_spec
        from dgtd.scenarios.user import learning_env

        table = {"make": values["env_make"], "agents": own["agents"]} | {k: values.get(k) for k in ENV_FIELDS}
        env, network, _ = learning_env(env_spec(table), _given(values, "gamma", 0.9), network_for)
        return env, network
    N = 3 if own["agents"] is None else int(own["agents"])
    if N < 2:
        raise DgtdInputError(f"{task} needs at least 2 agents, got {N}")
    return EnvTask(partial(make_spread, N), spread_features(N), _given(values, "gamma", 0.9), task, N), network_for(N)


def _given(values: dict, name: str, default):
    value = values.get(name)
    return default if value is None else value
