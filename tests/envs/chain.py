"""Tiny environments for the tests of `dgtd run --env`: a PettingZoo chain whose model is known, and bad ones."""

from __future__ import annotations

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

P = np.array([[0.1, 0.6, 0.3, 0.0], [0.0, 0.2, 0.5, 0.3], [0.4, 0.0, 0.2, 0.4], [0.5, 0.2, 0.0, 0.3]])
R = np.array([[1.0, 0.0, 0.0, 2.0], [0.0, 3.0, 0.0, 0.0], [0.5, 0.5, 1.0, 0.0], [0.0, 0.0, 2.0, 1.0]])
GAMMA = 0.8


class Chain(ParallelEnv):
    """Four states moving by P whatever the agents do; agent i earns R[i, s] at state s; the state is its index."""

    metadata = {"name": "chain_v1"}

    def __init__(self, n_agents: int = 3, nan_after: int | None = None):
        self.possible_agents = [f"agent_{i}" for i in range(n_agents)]
        self.agents, self.s, self.steps, self.nan_after = [], 0, 0, nan_after
        self.rng = np.random.default_rng()
        self.state_space = spaces.Discrete(4)

    def observation_space(self, agent):
        return spaces.Discrete(4)

    def action_space(self, agent):
        return spaces.Discrete(2)

    def state(self):
        self.steps += 1
        return np.array([np.nan if self.nan_after is not None and self.steps > self.nan_after else self.s])

    def reset(self, seed=None, options=None):
        self.rng = np.random.default_rng(seed)
        self.agents = list(self.possible_agents)
        self.s = int(self.rng.integers(4))
        return {a: self.s for a in self.agents}, {a: {} for a in self.agents}

    def step(self, actions):
        rewards = {a: R[i, self.s] for i, a in enumerate(self.agents)}
        self.s = int(self.rng.choice(4, p=P[self.s]))
        return (
            {a: self.s for a in self.agents},
            rewards,
            {a: False for a in self.agents},
            {a: False for a in self.agents},
            {a: {} for a in self.agents},
        )


def make_chain(n_agents: int = 3):
    return Chain(n_agents)


def make_nan_chain():
    return Chain(3, nan_after=50)


def make_nothing():
    return object()


def widening_features(states):
    """Features whose width changes with the batch: wrong."""
    return np.ones((len(states), 2 + len(states) % 3))


def stay(agent, observation, space, rng):
    return 0


def team_rewards(rewards: dict):
    """Every agent gets the team's total: a reward mapping (the [env] table's rewards)."""
    total = sum(rewards.values())
    return [total] * len(rewards)


class BadRewards(Chain):
    """A chain whose step() goes wrong in one of the ways a user's env does: ``how`` names it."""

    def __init__(self, how: str):
        super().__init__(3)
        self.how = how

    def step(self, actions):
        if self.how == "raises":
            raise RuntimeError("the user's step() failed")
        obs, rewards, terms, truncs, infos = super().step(actions)
        if self.how == "missing":
            rewards.pop("agent_2")
        elif self.how == "text":
            rewards = {a: "high" for a in rewards}
        elif self.how == "extra":
            rewards["agent_9"] = 1.0
        elif self.how == "none":
            rewards = None
        return obs, rewards, terms, truncs, infos


def make_raising():
    return BadRewards("raises")


def make_missing_reward():
    return BadRewards("missing")


def make_text_reward():
    return BadRewards("text")


def make_extra_reward():
    return BadRewards("extra")


def make_no_rewards():
    return BadRewards("none")


def raising_policy(agent, observation, space, rng):
    raise KeyError("the user's policy failed")


def raising_features(states):
    raise ZeroDivisionError("the user's features failed")


def make_without_state_space():
    """A chain whose state() works but which declares no state_space."""
    env = Chain(3)
    del env.state_space
    return env


class OldGym:
    """A single-agent env of the old Gym API (before gym 0.26): reset() returns only the observation and step()
    four values (observation, reward, done, info)."""

    observation_space = spaces.Box(-1.0, 1.0, (2,))
    action_space = spaces.Discrete(2)

    def reset(self, seed=None, options=None):
        return np.zeros(2)

    def step(self, action):
        return np.zeros(2), 1.0, False, {}


def make_old_gym():
    return OldGym()


class OldParallel(Chain):
    """A ParallelEnv of the old PettingZoo API: reset() returns only the observations, step() four dicts."""

    def reset(self, seed=None, options=None):
        return super().reset(seed, options)[0]

    def step(self, actions):
        obs, rewards, terms, truncs, infos = super().step(actions)
        return obs, rewards, {a: terms[a] or truncs[a] for a in terms}, infos


def make_old_parallel():
    return OldParallel(3)


class TextChain(Chain):
    """A chain whose state and observations are words."""

    def state(self):
        return f"state {self.s}"

    def reset(self, seed=None, options=None):
        obs, infos = super().reset(seed, options)
        return {a: f"state {o}" for a, o in obs.items()}, infos


def make_text_chain():
    return TextChain(3)


class StrangerAgents(Chain):
    """reset() makes agents other than its possible_agents, and observes them (no state(): the observations are it)."""

    def state(self):
        raise NotImplementedError

    def reset(self, seed=None, options=None):
        super().reset(seed, options)
        self.agents = [f"stranger_{i}" for i in range(len(self.possible_agents))]
        return {a: self.s for a in self.agents}, {a: {} for a in self.agents}


def make_stranger_agents():
    return StrangerAgents()


class BoxActions(Chain):
    """The chain with continuous actions."""

    def action_space(self, agent):
        return spaces.Box(-1.0, 1.0, (2,))


def make_box_actions():
    return BoxActions()


class NoAgents(Chain):
    """The chain with nobody in it."""

    def __init__(self):
        super().__init__(0)


def make_no_agents():
    return NoAgents()
