"""`mpe-spread`: MPE2's simple_spread (cooperative navigation) evaluated by agents that each see their own reward.

N particles and N landmarks in the plane (Lowe et al. 2017; MPE2, the Farama Foundation's maintained version). The
policy is a fixed heuristic: particle i heads for landmark i along its larger coordinate gap, with a random action
one time in five (so that the states spread). Each agent's reward is its own PettingZoo reward (the team's
coverage term, minus its own collisions). Two agents exchange parameters only while they are within ``radius`` of
each other (`dgtd.graphs.proximity.ProximityNetwork` on the particles' positions), so the network changes with the
particles' motion, as in the paper's Example 2.

The value function is linear in features of the global state (`spread_features`): a constant, and for each
landmark the distance to its nearest particle and its square: the reward is minus the sum of those distances, so
the values are close to linear in them. DGTD's step size is that of every run without a model
(`dgtd.scenarios.user.scaled_dgtd`: alpha0 = 10 / E|phi|^2, within what the graph allows, as all agents may be
linked); it ends within 5 % of the reference after 60,000 steps (docs/environments.md).

There is no model: the reference is LSTD on independent episodes (`dgtd.sources.env.reference_from_env`), and
the mean graph (for mu* and the connectivity check) is the link frequencies measured on those episodes. Episodes
last 25 steps (MPE2's default); a time limit is not terminal, so the TD target bootstraps from the state reached.
After the run, ``values.png`` shows every agent's value estimate along a fresh trajectory against the reference.
"""

from __future__ import annotations

from functools import partial
from typing import Any

import numpy as np

from dgtd.errors import DgtdInputError

MAX_CYCLES = 25
MOVES = ((0.0, 0.0), (-1.0, 0.0), (1.0, 0.0), (0.0, -1.0), (0.0, 1.0))  # MPE's discrete actions 0..4
POLICIES = ("heuristic", "random")


def make_spread(n_agents: int):
    """A fresh simple_spread ParallelEnv with discrete actions (MPE2's own defaults otherwise)."""
    try:
        from mpe2 import simple_spread_v3
    except ImportError:
        raise DgtdInputError("mpe-spread needs MPE2: pip install 'dgtd[envs]'") from None
    return simple_spread_v3.parallel_env(N=int(n_agents), max_cycles=MAX_CYCLES, continuous_actions=False)


def spread_policy(n_agents: int, epsilon: float = 0.2):
    """Particle i moves towards landmark i along its larger coordinate gap; a random move with probability epsilon.

    An agent's observation is (velocity 2, position 2, landmarks relative 2N, other particles 2(N-1), messages
    2(N-1)), so landmark i relative to it is observation[4 + 2i : 6 + 2i]."""

    def policy(agent: str, observation, space, rng: np.random.Generator) -> int:
        if rng.random() < epsilon:
            return int(rng.integers(len(MOVES)))
        i = int(agent.rsplit("_", 1)[1])
        gap = np.asarray(observation[4 + 2 * i : 6 + 2 * i], dtype=np.float64)
        axis = int(np.argmax(np.abs(gap)))
        return (1 if gap[0] < 0 else 2) if axis == 0 else (3 if gap[1] < 0 else 4)

    return policy


def spread_features(n_agents: int):
    """features(states (K, 6N^2 ...)) -> (K, 1 + 2N): 1, each landmark's distance to its nearest particle, squared."""
    N = int(n_agents)

    def features(states: np.ndarray) -> np.ndarray:
        obs = np.asarray(states, dtype=np.float64).reshape(len(states), N, -1)
        pos = obs[:, :, 2:4]  # (K, N, 2) the particles
        landmarks = pos[:, :1, :] + obs[:, 0, 4 : 4 + 2 * N].reshape(-1, N, 2)  # (K, N, 2) from particle 0's view
        dist = np.linalg.norm(pos[:, :, None, :] - landmarks[:, None, :, :], axis=-1).min(axis=1)  # (K, N)
        return np.concatenate([np.ones((len(obs), 1)), dist, dist**2], axis=1)

    return features


def agent_positions(env) -> np.ndarray:
    """The particles' positions (N, 2), what the proximity network links."""
    return np.array([a.state.p_pos for a in env.unwrapped.world.agents])


def mpe_spread(
    agents: int = 3,
    radius: float = 1.0,
    gamma: float = 0.9,
    iterations: int = 60_000,
    reference_steps: int = 4000,
    reference_groups: int = 8,
    epsilon: float = 0.2,
    policy: str = "heuristic",
):
    """MPE2 simple_spread, N agents (3), linked within ``radius`` (1.0), DGTD scaled to the features; LSTD reference.
    ``policy``: "heuristic" (`spread_policy`) or "random" (uniform over the 5 moves)."""
    from dgtd.graphs.proximity import ProximityNetwork
    from dgtd.scenarios.base import Scenario
    from dgtd.scenarios.user import (
        REFERENCE_SEED_OFFSET,
        TRAJECTORY_SEED_OFFSET,
        TrajectoryReport,
        compare_note,
        compare_steps,
        mean_proximity_network,
        scaled_dgtd,
    )
    from dgtd.sources.env import EnvSource, reference_from_env
    from dgtd.sources.model import Sampling

    N = int(agents)
    if N < 2:
        raise DgtdInputError(f"mpe-spread needs at least 2 agents, got {N}")
    if policy not in POLICIES:
        raise DgtdInputError(f"mpe-spread's policy is one of {', '.join(POLICIES)}, got {policy!r}")
    proximity = ProximityNetwork(N, float(radius))
    chosen = spread_policy(N, epsilon) if policy == "heuristic" else "random"
    common: dict[str, Any] = dict(policy=chosen, positions=agent_positions, proximity=proximity)
    features = spread_features(N)
    reference, link_frequency = reference_from_env(
        lambda g: EnvSource(partial(make_spread, N), features, 0, [g], seed_offset=REFERENCE_SEED_OFFSET, **common),
        1 + 2 * N,
        gamma,
        "mpe-spread",
        steps=int(reference_steps),
        groups=int(reference_groups),
    )
    return Scenario(
        problem=reference,
        network=mean_proximity_network(proximity, link_frequency),
        algorithm=scaled_dgtd(reference, proximity.base),
        sampling=Sampling(mode="markov", shared=True),
        iterations=int(iterations),
        description=f"MPE2 simple_spread, {N} agents linked within {radius:g}, {policy} policy, LSTD reference",
        source=lambda seed, seed_ids: EnvSource(partial(make_spread, N), features, seed, seed_ids, **common),
        report=TrajectoryReport(
            lambda: EnvSource(partial(make_spread, N), features, 0, [0], seed_offset=TRAJECTORY_SEED_OFFSET, **common),
            steps=100,
        ),
        compare_settings=compare_steps(reference.moments),
        compare_note=compare_note(reference.moments),
    )
