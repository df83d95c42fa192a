"""A single-agent Gymnasium environment as N agents that each see a share of its one reward.

The paper's agents each get a local reward whose average over agents is the reward the team is evaluated on
(section 3). A Gymnasium env has one reward r; `SplitReward` presents it through PettingZoo's parallel API (what
`dgtd.sources.env.EnvSource` runs) with agent i's reward

- ``N w_i r`` for a partition ``w`` the user gives (w_i >= 0, sum 1): e.g. one agent sees all of it, or
- ``N w_i r`` with ``w`` drawn afresh at every step from the flat Dirichlet distribution (``split="random"``): no
  agent can learn the value alone, yet the agents' rewards average to r exactly at every step.

The agents share the environment's one action: agent 0's policy chooses it (the others' actions are ignored), and
every agent observes the env's observation, which is also the state the value function is defined on.
"""

from __future__ import annotations

import numpy as np

from dgtd.errors import DgtdInputError

PARALLEL_API = (
    "PettingZoo's ParallelEnv API (pettingzoo >= 1.22): reset() -> (observations, infos), step() -> "
    "(observations, rewards, terminations, truncations, infos)"
)
GYMNASIUM_API = (
    "Gymnasium's API (gymnasium, or gym >= 0.26): reset() -> (observation, info), step() -> "
    "(observation, reward, terminated, truncated, info)"
)


def api_checked(result, size: int, what: str, api: str):
    """``result`` of a user's env's reset() or step() (``what``), where it is the tuple of ``size`` values ``api``
    gives; else a one-line refusal saying it is an older API and which one dgtd needs (unpacking it would raise
    deep in dgtd)."""
    if isinstance(result, tuple) and len(result) == size:
        return result
    got = f"{len(result)} values" if isinstance(result, tuple) else f"a {type(result).__name__}"
    old = "Gym" if api is GYMNASIUM_API else "PettingZoo"
    raise DgtdInputError(f"{what} returned {got}, not {size}: the old {old} API; dgtd needs {api}")


def split_weights(split, n_agents: int) -> np.ndarray | None:
    """The partition w (N,) of ``split`` (a list), or None for "random"; a bad one is a one-line error."""
    if isinstance(split, str):
        if split != "random":
            raise DgtdInputError(f"split must be 'random' or a list of {n_agents} shares that sum to 1, got {split!r}")
        return None
    w = np.asarray(split, dtype=np.float64)
    if w.shape != (n_agents,) or np.any(w < 0) or not np.isclose(w.sum(), 1.0):
        raise DgtdInputError(f"split must hold {n_agents} shares >= 0 that sum to 1 (one per agent), got {list(split)}")
    return w


class SplitReward:
    """``env`` (a gymnasium.Env) as a ParallelEnv of ``n_agents`` agents whose rewards average to the env's reward."""

    metadata = {"name": "split_reward"}

    def __init__(self, env, n_agents: int, split="random"):
        if int(n_agents) < 2:
            raise DgtdInputError(f"a Gymnasium env's reward is split among N >= 2 agents; got agents = {n_agents}")
        self.env = env
        self.possible_agents = [f"agent_{i}" for i in range(int(n_agents))]
        self.agents = list(self.possible_agents)
        self.weights = split_weights(split, len(self.possible_agents))
        self.rng = np.random.default_rng(0)
        self.obs = None

    def observation_space(self, agent):
        return self.env.observation_space

    def action_space(self, agent):
        return self.env.action_space

    def state(self) -> np.ndarray:
        return np.ravel(np.asarray(self.obs, dtype=np.float64))

    def reset(self, seed: int | None = None, options=None):
        what = f"the env's reset() ({type(self.env).__name__})"
        self.obs, info = api_checked(self.env.reset(seed=seed, options=options), 2, what, GYMNASIUM_API)
        self.rng = np.random.default_rng(seed)  # the random split's own stream, from the same seed
        self.agents = list(self.possible_agents)
        return {a: self.obs for a in self.agents}, {a: info for a in self.agents}

    def step(self, actions: dict):
        what = f"the env's step() ({type(self.env).__name__})"
        result = api_checked(self.env.step(actions[self.possible_agents[0]]), 5, what, GYMNASIUM_API)
        self.obs, reward, terminated, truncated, info = result
        N = len(self.possible_agents)
        w = self.rng.dirichlet(np.ones(N)) if self.weights is None else self.weights
        rewards = N * w * float(reward)
        if terminated or truncated:
            self.agents = []
        agents = self.possible_agents
        return (
            {a: self.obs for a in agents},
            {a: float(x) for a, x in zip(agents, rewards)},
            {a: bool(terminated) for a in agents},
            {a: bool(truncated) for a in agents},
            {a: info for a in agents},
        )

    def close(self) -> None:
        self.env.close()

    @property
    def unwrapped(self):
        return self.env.unwrapped
