"""Random problems for tests, benchmarks and experiments; every generator takes an explicit Generator."""

from __future__ import annotations

import numpy as np

from dgtd.problems.model import Problem, make_problem


def random_problem(
    n_states: int,
    n_agents: int,
    n_features: int,
    rng: np.random.Generator,
    *,
    gamma: float = 0.9,
    sigma: float = 1.0,
    reward_noise: str = "none",
    name: str = "random",
) -> Problem:
    """A dense random ergodic chain with random nonnegative features and agent rewards in [0, sigma].

    P has positive entries (so the chain is ergodic and aperiodic); Phi = I when n_features == n_states,
    else uniform [0, 1) entries (full column rank with probability one, checked by `make_problem`).
    """
    P = rng.random((n_states, n_states)) + 0.05
    P /= P.sum(axis=1, keepdims=True)
    R = sigma * rng.random((n_agents, n_states))
    Phi = np.eye(n_states) if n_features == n_states else rng.random((n_states, n_features))
    return make_problem(P, R, Phi, gamma, sigma=sigma, reward_noise=reward_noise, name=name)


def random_mdp_problem(
    n_states: int,
    action_sizes: tuple,
    n_features: int,
    rng: np.random.Generator,
    *,
    gamma: float = 0.9,
    off_policy: bool = True,
    name: str = "random-mdp",
) -> Problem:
    """A random multi-agent MDP (one local action set per agent) reduced by `from_mdp`, optionally off-policy."""
    from dgtd.problems.mdp import from_mdp

    N = len(action_sizes)
    A = int(np.prod(action_sizes))
    P = rng.random((n_states, A, n_states)) + 0.05
    P /= P.sum(axis=2, keepdims=True)
    rewards = rng.random((N, n_states, A, n_states))
    Phi = rng.random((n_states, n_features))

    def policies():
        out = []
        for a in action_sizes:
            p = rng.random((n_states, a)) + 0.1
            out.append(p / p.sum(axis=1, keepdims=True))
        return out

    target = policies()
    behaviour = policies() if off_policy else None
    return from_mdp(P, rewards, Phi, gamma, target, behaviour, name=name)
