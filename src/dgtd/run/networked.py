"""Learning runs on networked systems (agents with local states: `dgtd.problems.networked`, `dgtd.problems.wireless`):
one typed configuration (`NetworkedConfig`, which makes `dgtd networked`'s options), the named tasks, the run of Qu,
Wierman and Li's scalable actor-critic with its evaluation, and the comparison of networked learners (kappa hops),
independent ones (0 hops: each critic its own state and action) and the task's heuristic, on the same keyed numbers."""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field, fields

import numpy as np

from dgtd.errors import DgtdInputError
from dgtd.fields import option
from dgtd.run.layout import learner_layout
from dgtd.run.scalable import ScalableSteps, learn_scalable, rollout_return, uniform_policies
from dgtd.run.settings import check_count
from dgtd.streams import seed_keys

TASKS = {
    "wireless-access": "Qu et al.'s wireless access: a grid of cells, 2 users a cell, 3 rows (--agents 24: 3 x 4)",
    "random-networked": "a random networked MDP on a ring (--agents 10), 2 states and actions an agent",
    "epidemic": "an SIS epidemic on a 10-row torus grid (--agents 100, a multiple of 10), treat or wait",
}
SENDS = np.arange(20) / 20  # the ALOHA-like heuristics' send probabilities (their code's 20)


@dataclass(frozen=True)
class NetworkedConfig:
    """Every setting of a networked learning run, with its option; defaults: the published wireless benchmark's."""

    problem_file: str | None = field(default=None, metadata=option("A networked MDP file (.npz: edges, P, R, gamma, "
                                     "start; docs/control.md) to learn on instead of a named task.",
                                     flags=("--problem",), metavar="FILE.npz"))  # fmt: skip
    agents: int | None = field(default=None, metadata=option("Agents: wireless-access's users (a grid of 2 a cell and "
                               "3 rows; default 24) or random-networked's ring (default 10)."))  # fmt: skip
    hops: int = field(default=1, metadata=option("kappa: the hops of each critic's neighbourhood (0: independent "
                      "learners, each critic its own state and action)."))  # fmt: skip
    horizon: int = field(default=10, metadata=option("T: an episode's steps after its first."))
    episodes: int = field(default=120_000, metadata=option("Episodes to learn for.", flags=("--episodes", "-T")))
    seeds: int = field(default=1, metadata=option("Seeds, run at once (an array axis)."))
    seed: int = field(default=0, metadata=option("The base seed every random number is keyed by."))
    every: int = field(default=2_000, metadata=option("Episodes between evaluations of the policies."))
    rollouts: int = field(default=400, metadata=option("Keyed rollouts an evaluation averages."))
    critic_step: float = field(default=1.0, metadata=option("The critics' step h in h / (tau - 1 + t0)^p."))
    critic_offset: float = field(default=1.0, metadata=option("The critics' step offset t0."))
    critic_power: float = field(default=0.5, metadata=option("The critics' step power p."))
    actor_step: float = field(default=5.0 / 24, metadata=option("The actors' step eta on the sum of the values within "
                              "kappa hops (their code's 5 on the mean of 24 users'; kept as n grows)."))  # fmt: skip
    restart: int = field(default=100, metadata=option("Episodes after which both steps start again, the critics' "
                         "tables kept (their code's form); 0: tables from 0 each episode (the paper's)."))  # fmt: skip
    loss: float = field(
        default=0.0,
        metadata=option(
            "Each message an agent needs from another within kappa hops "
            "(its state and action, its value) is lost with this probability, by its own keyed number."
        ),
    )
    forget: bool = field(default=False, metadata=option("The critics' tables start from 0 at each restart too: they "
                         "hold at most --restart episodes' configurations (many agents' memory)."))  # fmt: skip

    def __post_init__(self):
        for name in ("hops", "seed", "restart"):
            check_count(name, getattr(self, name), 0)
        for name in ("horizon", "episodes", "seeds", "every", "rollouts"):
            check_count(name, getattr(self, name), 1)
        if self.agents is not None:
            check_count("agents", self.agents, 1)

    @property
    def steps(self) -> ScalableSteps:
        """The scalable actor-critic's steps."""
        c = self
        return ScalableSteps(c.hops, c.horizon, c.critic_step, c.critic_offset, c.actor_step, c.critic_power, c.restart,
                             c.forget)  # fmt: skip


def task_of(name: str | None, agents: int | None, problem_file: str | None = None):
    """The named task at ``agents`` agents (its default size where None), or a networked MDP file's."""
    if (name is None) == (problem_file is None):
        raise DgtdInputError(f"name a networked task ({', '.join(TASKS)}) or give --problem FILE.npz, one of them")
    if problem_file is not None:
        from dgtd.problems.networked import load_networked

        if agents is not None:
            raise DgtdInputError("--agents sizes a named task; a networked MDP file's agents are its arrays'")
        return load_networked(problem_file)
    if name == "wireless-access":
        from dgtd.problems.wireless import grid

        n = 24 if agents is None else agents
        width = max(2, -(-n // 6))  # (3 rows of cells, 2 users a cell)
        if n != 6 * width:
            raise DgtdInputError(f"wireless-access has 2 users a cell in 3 rows: --agents a multiple of 6 from 12 "
                                 f"(e.g. {6 * width}); got {n}")  # fmt: skip
        return grid(3, width, 2)
    if name == "random-networked":
        from dgtd.graphs import topologies
        from dgtd.problems.networked import random_networked

        n = 10 if agents is None else agents
        if n < 3:
            raise DgtdInputError(f"random-networked is a ring: --agents 3 or more; got {n}")
        return random_networked(topologies.ring(n).edges, n, gamma=0.7)
    if name == "epidemic":
        from dgtd.problems.epidemic import epidemic

        n = 100 if agents is None else agents
        if n % 10 or n < 30:
            raise DgtdInputError(f"epidemic is a torus grid of 10 rows: --agents a multiple of 10 from 30; got {n}")
        return epidemic(torus(10, n // 10), n)
    raise DgtdInputError(f"name a networked task: {', '.join(TASKS)}; got {name!r}")


def torus(rows: int, columns: int) -> np.ndarray:
    """(E, 2) the edges of a rows x columns grid whose ends wrap (agent r columns + c at row r, column c)."""
    at = np.arange(rows * columns).reshape(rows, columns)
    return np.concatenate([np.stack([at.ravel(), np.roll(at, -1, axis=1).ravel()], axis=1),
                           np.stack([at.ravel(), np.roll(at, -1, axis=0).ravel()], axis=1)])  # fmt: skip


def heuristics(name: str | None, task) -> dict:
    """{its name: local policies} of the task's heuristics: wireless access's 20 ALOHA-like policies (their code's send
    probabilities), the epidemic's never, always and while infected treatments; none for a random one."""
    if name == "wireless-access":
        return {f"ALOHA-like, send probability {p:.2f}": task.aloha(p) for p in SENDS}
    if name == "epidemic":
        from dgtd.problems.epidemic import heuristics as treatments

        return treatments(task)
    return {}


def heuristic(name: str | None, task, config: NetworkedConfig) -> dict | None:
    """The task's best heuristic, each one's return from the same keyed rollouts: {"return" (B,), "policy" its name,
    "of" how many were tried, "tried" {name: mean return}}; None where the task has none."""
    tried = heuristics(name, task)
    if not tried:
        return None
    keys = seed_keys(config.seed, range(config.seeds))
    values = {label: rollout_return(task, p, keys, config.rollouts, config.horizon) for label, p in tried.items()}
    best = max(values, key=lambda label: values[label].mean())
    tried_means = {label: float(v.mean()) for label, v in values.items()}
    return {"return": values[best], "policy": best, "of": len(values), "tried": tried_means}


def learn_networked(task, config: NetworkedConfig, progress=None, on_measured=None, **saves) -> dict:
    """A run of the scalable actor-critic on ``task`` (`task_of`'s): {"agents", "episodes" (C + 1,), "return" (C + 1,
    B) the evaluated return (episode 0: the uniform starting policies), "episode_return" (C, B), "policies" (on the
    process that writes), "seconds"}; ``on_measured(episodes, returns)`` with the evaluations so far, the start's
    first, as each is made; ``saves``: `learn_scalable`'s checkpoint arguments. Under mpiexec the agents are spread
    over the ranks (`dgtd.run.layout.learner_layout`), every number one process's."""
    keys = seed_keys(config.seed, range(config.seeds))
    layout = learner_layout(task.n_agents)
    start = rollout_return(task, uniform_policies(task)[layout.local], keys, config.rollouts, config.horizon, 0, layout)
    began = time.perf_counter()

    def measured(episodes, returns):
        if on_measured is not None:
            on_measured(np.r_[0, episodes], np.vstack([start, returns]))

    measured(np.zeros(0, dtype=np.int64), np.zeros((0, config.seeds)))
    out = learn_scalable(task, config.steps, config.episodes, config.seeds, config.seed,
                         max(1, config.episodes // config.every), config.rollouts, progress, config.loss,
                         measured, layout=layout, **saves)  # fmt: skip
    return {
        "agents": task.n_agents, "episodes": np.r_[0, out["iterations"]],
        "return": np.vstack([start, out["evaluated"]]), "episode_return": out["episode_return"],
        "policies": out["policies"], "seconds": time.perf_counter() - began,
    }  # fmt: skip


def compare_networked(task, config: NetworkedConfig, progress=None) -> dict:
    """{learner: `learn_networked`'s result}: networked learners (kappa = ``config.hops``, at least 1) and independent
    ones (kappa 0) on ``task``, on the same keyed numbers (seeds, episodes, rollouts)."""
    hops = max(1, config.hops)
    runs = {f"networked (kappa {hops})": NetworkedConfig(**{**asdict(config), "hops": hops}),
            "independent (kappa 0)": NetworkedConfig(**{**asdict(config), "hops": 0})}  # fmt: skip
    return {label: learn_networked(task, c, progress) for label, c in runs.items()}


def config_from(values: dict) -> NetworkedConfig:
    """The configuration of the options given (None: not given)."""
    names = {f.name for f in fields(NetworkedConfig)}
    return NetworkedConfig(**{k: v for k, v in values.items() if k in names and v is not None})
