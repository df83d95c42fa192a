"""`dgtd learn`'s configuration: the task the agents learn on, the actors, and what the command shares with `dgtd
run` (the critic by `--algorithm` and its steps, the network and its links, the run's length and seeds), each option
made from its field as `dgtd run`'s are, checked here in one place.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from types import SimpleNamespace

from dgtd.errors import DgtdInputError
from dgtd.fields import option

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
            "critic's first steps favour the actions sampled most and need the slower actor)."
        ),
    )
    actor_offset: float = field(default=1000.0, metadata=option("The actor's steps: offset."))
    actor_power: float = field(
        default=0.8, metadata=option("The actor's steps: power, in (1/2, 1] so that the critic is the faster.")
    )
    values: str | None = field(
        default=None,
        metadata=option(
            "What the critics evaluate: state (values V and a consensus estimate of the team's reward, Zhang et al.'s "
            "Algorithm 2; the default) or action (values Q on additive features of the state and joint action, their "
            "Algorithm 1)."
        ),
    )
    batch: int | None = field(
        default=None,
        metadata=option(
            "Steps of a round (Chen et al.'s mini-batches): the agents communicate and move once a round, by the "
            "mean of its samples (default 1).",
            metavar="M",
        ),
    )


SHARED = (
    "problem_file", "algorithm", "alpha0", "beta", "schedule", "graph", "edge_prob", "loss", "burst", "reweight",
    "delay", "wake", "bits", "top_k", "error_feedback", "iterations", "seeds", "seed", "checkpoints",
)  # fmt: skip
"""The options `dgtd learn` shares with `dgtd run`."""


def resolve_learning(task: str | None, values: dict) -> SimpleNamespace:
    """The pieces of a learning run from the command's option values (flat names, None where not given): the team MDP,
    the network, the channel, the critic, the actor and the settings, and the record of what was asked."""
    from dgtd.algorithms import make_algorithm
    from dgtd.algorithms.actor import SoftmaxActor
    from dgtd.config import _network, build_algorithm, channel_for
    from dgtd.problems.team import TASKS
    from dgtd.run.learn import LearnSettings

    own = {f.name: values.get(f.name) for f in fields(LearnConfig)}
    file = values.get("problem_file")
    if (task is None) == (file is None):
        raise DgtdInputError(f"name one learning task ({', '.join(TASKS)}) or --problem FILE.npz; got {task!r}")
    if file is not None:
        from dgtd.problems.io import load_team_mdp

        if own["agents"] is not None or own["states"] is not None:
            raise DgtdInputError("--agents and --states size a named task; a problem file's sizes are its arrays'")
        mdp = load_team_mdp(file)
    elif task not in TASKS:
        raise DgtdInputError(f"name a learning task: {', '.join(TASKS)}; got {task!r}")
    else:
        sizes = {k: v for k, v in (("n_agents", own["agents"]), ("n_states", own["states"])) if v is not None}
        mdp = TASKS[task](**sizes)
    network = _network(values.get("graph") or "ring", mdp.n_agents, _given(values, "edge_prob", 1.0))
    links = {k: values.get(k) for k in ("delay", "wake", "bits", "top_k", "error_feedback")}
    channel = channel_for(values.get("loss"), values.get("burst"), network, values.get("reweight"), links)
    spec = SimpleNamespace(
        algorithm=values.get("algorithm"),
        algorithm_params=None,
        **{k: values.get(k) for k in ("alpha0", "beta", "schedule", "kappa", "rho")},
    )
    critic = build_algorithm(spec, make_algorithm("dgtd", **CRITIC_STEPS))
    step = _given(own, "actor_step", ACTOR_STEP[_given(own, "values", "state")])
    actor = SoftmaxActor(step, _given(own, "actor_offset", 1000.0), _given(own, "actor_power", 0.8))
    settings = LearnSettings(
        iterations=_given(values, "iterations", 20_000),
        seeds=_given(values, "seeds", 2),
        seed=_given(values, "seed", 0),
        checkpoints=_given(values, "checkpoints", 40),
        actor=_given(own, "actor", "networked"),
        batch=_given(own, "batch", 1),
        values=_given(own, "values", "state"),
    )
    record = {"task": task, **{k: v for k, v in {**values, **own}.items() if v is not None}}
    if file is not None:
        from dgtd.problems.io import file_digest

        record["problem_sha256"] = file_digest(file)
    return SimpleNamespace(
        mdp=mdp, network=network, channel=channel, critic=critic, actor=actor, settings=settings, record=record
    )


def _given(values: dict, name: str, default):
    value = values.get(name)
    return default if value is None else value
