"""What learners act in (`dgtd.run.learn`): one protocol for a model's step and a simulator's, so that one learning
loop runs both.

An environment says what its agents' actors see (``start``, and each `Step`'s ``seen``), takes every agent's action
and returns the `Step`: the critics' features of the state left and the state reached, each agent's own reward,
whether the transition continues (a terminal one's TD target is its reward alone), and g(s), the state's part of the
team-reward regression's features f(s, a) = (g(s) e_{a_1}^T, ..., g(s) e_{a_N}^T) (`dgtd.algorithms.team_reward`).

- `ModelEnv`: a team MDP (a joint table, or a factored one), its steps drawn from the keyed streams as `dgtd run`
  draws a shared trajectory's (SHARED_START, SHARED_STATE); the actors see the state (a tabular softmax), g(s) = e_s;
  its exact return and critics are computed from the model.
- `SimulatorEnv`: a PettingZoo ParallelEnv (`EnvTask`), one copy a seed (`dgtd.sources.env.EnvSource`); each actor
  sees x_i = (o_i, 1), its own observation (a linear softmax), g(s) = phi(s); the return is estimated from the run's
  own rewards, and its state cannot be saved (no checkpoints).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from dgtd.algorithms.actor import LinearSoftmaxActor, SoftmaxActor
from dgtd.errors import DgtdInputError
from dgtd.problems import team
from dgtd.streams import SHARED_START, SHARED_STATE, uniforms

BLOCK = 512  # steps whose random numbers are drawn together


@dataclass
class Step:
    """One step of every seed: ``seen`` what the actors see next; ``phi`` and ``phi_next`` (B, 1, q) the critics'
    features of the states left and reached; ``rewards`` (B, N) each agent's own; ``going`` (B,) 0 where the
    transition is terminal, else 1 (None: always 1); ``g`` the state's regression features, (B,) indices of a
    one-hot g(s) or (B, m); ``state``, ``state_next`` the model's states (None in a simulator); ``ended`` (B,) where
    an episode ended at this step (a simulator's)."""

    seen: Any
    phi: np.ndarray
    phi_next: np.ndarray
    rewards: np.ndarray
    going: np.ndarray | None
    g: np.ndarray
    state: np.ndarray | None = None
    state_next: np.ndarray | None = None
    ended: np.ndarray | None = None


class ModelEnv:
    """A team MDP's steps for B seeds of keys ``keys`` (see the module's docstring)."""

    estimated = False

    def __init__(self, mdp, keys: np.ndarray):
        self.mdp, self.keys = mdp, keys
        self.name, self.n_agents, self.actions = mdp.name, mdp.n_agents, np.asarray(mdp.actions)
        self.n_features = mdp.n_features  # the critics' q
        self._drawn: tuple = (-1, None)  # (a block's first step, its uniforms)

    def actor(self, actor: SoftmaxActor) -> SoftmaxActor:
        return actor

    def theta(self, actor: SoftmaxActor, seeds: int) -> np.ndarray:
        """Every agent's starting parameters: uniform policies, or the problem's starting ones where given."""
        theta = actor.init(seeds, self.mdp.actions, self.mdp.n_states)
        if getattr(self.mdp, "policies", None) is not None:
            theta = actor.starting_at(theta, self.mdp.policies)
        return theta

    def regression_size(self, n_actions: int) -> int:
        """The length of f(s, a): N A S (g(s) = e_s)."""
        return self.n_agents * n_actions * self.mdp.n_states

    def start(self) -> np.ndarray:
        """Each seed's first state (B,)."""
        return team.draw(np.cumsum(self.mdp.start), uniforms(self.keys, SHARED_START, 0, 0)[0])

    def step(self, s: np.ndarray, a: np.ndarray, k: int) -> Step:
        """Step k from states ``s`` (B,) under the joint actions ``a`` (B, N)."""
        first = k - k % BLOCK
        if self._drawn[0] != first:  # a block's numbers at once: each a pure function of (seed, purpose, step)
            steps = np.arange(first, first + BLOCK, dtype=np.uint64)[:, None]
            self._drawn = (first, uniforms(self.keys[None, :], SHARED_STATE, steps, 0))  # two a step (T, B) each
        u = self._drawn[1]
        s_next, r = self.mdp.step(s, a, (u[0][k - first], u[1][k - first]))
        Phi = self.mdp.Phi
        return Step(s_next, Phi[s][:, None, :], Phi[s_next][:, None, :], r, None, s, s, s_next)


@dataclass(frozen=True)
class EnvTask:
    """A simulator to learn in: ``make()`` a fresh PettingZoo ParallelEnv whose agents have the same discrete
    actions; ``features(states (K, dim)) -> (K, q)`` the critics' features of its global state (``env.state()``, else
    the observations joined); ``gamma`` the critics' discount; ``name`` as results name it; ``n_agents`` its
    agents; ``reward_map`` (rewards dict) -> (N,) where the env's rewards are not each agent's own."""

    make: Any
    features: Any
    gamma: float
    name: str
    n_agents: int
    reward_map: Any = None


class SimulatorEnv:
    """B copies of ``task``'s simulator, one a seed (see the module's docstring)."""

    estimated = True

    def __init__(self, task: EnvTask, network, seed: int, seeds: int):
        from dgtd.sources.env import EnvSource

        self.src = EnvSource(
            task.make, task.features, seed, range(seeds), network=network, name=task.name,
            reward_map=task.reward_map,
        )  # fmt: skip
        self.src.start()
        self.name, self.agents, self.seeds = task.name, self.src.agents, seeds
        N, A = len(self.agents), discrete_actions(self.src.spaces[0], self.src.name)
        if network.n_nodes != N or task.n_agents != N:
            raise DgtdInputError(
                f"the network has {network.n_nodes} agents, the env {N} (its task says {task.n_agents})"
            )
        self.n_agents, self.actions = N, np.full(N, A)
        self.n_features = self.src.features_of([self.src.current[0]]).shape[1]

    def actor(self, actor: SoftmaxActor) -> LinearSoftmaxActor:
        return LinearSoftmaxActor.like(actor)

    def theta(self, actor: SoftmaxActor, seeds: int) -> np.ndarray:
        return actor.init(seeds, self.actions, self.start().shape[-1])

    def regression_size(self, n_actions: int) -> int:
        """The length of f(s, a): N A q (g(s) = phi(s))."""
        return self.n_agents * n_actions * self.n_features

    def start(self) -> np.ndarray:
        """x_i = (o_i, 1) of every agent of each seed (B, N, d): its actor's features."""
        return observed(self.src, range(self.seeds))

    def step(self, x: np.ndarray, a: np.ndarray, k: int) -> Step:
        """One step of every seed's simulator under the actions ``a`` (B, N); a finished episode restarts."""
        src, B = self.src, self.seeds
        episodes = np.array(src.episodes)
        steps = [src.act(b, {agent: int(a[b, i]) for i, agent in enumerate(src.agents)}) for b in range(B)]
        phi = src.features_of([s[0] for s in steps] + [s[2] for s in steps])
        r, going = np.stack([s[1] for s in steps]), np.array([s[3] for s in steps], np.float64)  # (B, N), (B,)
        ended = np.array(src.episodes) > episodes  # (an episode ended at this step: the next began)
        return Step(self.start(), phi[:B, None, :], phi[B:, None, :], r, going, phi[:B], ended=ended)


def discrete_actions(spaces: dict, name: str) -> int:
    """The agents' common number of discrete actions, of their action ``spaces`` (agent -> space) in simulator
    ``name``: a softmax actor chooses among a Discrete space's actions, so anything else is one line."""
    discrete = [any(c.__name__ == "Discrete" for c in type(space).__mro__) for space in spaces.values()]
    counts = {int(getattr(space, "n", 0)) * ok for space, ok in zip(spaces.values(), discrete)}
    if len(counts) != 1 or min(counts) < 2:
        raise DgtdInputError(
            f"learners in {name} need every agent to have the same discrete actions (2 or more: a softmax actor "
            f"chooses among them); its action spaces: {', '.join(map(str, spaces.values()))}"
        )
    return counts.pop()


def observed(src, seeds) -> np.ndarray:
    """x_i = (o_i, 1) of every agent of each seed (B, N, d): its actor's features."""
    rows = []
    for b in seeds:
        obs = src.observations(b)
        rows.append([np.append(np.ravel(np.asarray(obs[a], np.float64)), 1.0) for a in src.agents])
    try:
        x = np.asarray(rows, dtype=np.float64)
    except ValueError:
        raise DgtdInputError(
            f"the agents' observations in {src.name} differ in size: an actor needs one size"
        ) from None
    if not np.isfinite(x).all():
        raise DgtdInputError(f"{src.name} returned NaN or infinite observations: an actor cannot act on them")
    return x
