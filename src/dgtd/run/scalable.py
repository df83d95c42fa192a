"""The scalable actor-critic of Qu, Wierman and Li ("Scalable reinforcement learning of localized policies for
multi-agent networked systems", L4DC 2020, Algorithm 1) on a networked MDP (`dgtd.problems.networked`), for B seeds
at once, every agent an array row.

Agent i's policy zeta_i(a_i | s_N_i) is a tabular softmax over its neighbourhood's states (`dgtd.algorithms.actor`,
one row a neighbourhood state); its critic Q^_i is a table over its kappa-hop neighbourhood's states and actions
(N_i^kappa: the agents within kappa hops). Iteration m (an episode of T + 1 steps, every number keyed by (seed,
purpose, step m (T + 1) + t, agent)):

    sample  s(0) from the start, then a_i(t) ~ zeta_i(. | s_N_i(t)), r_i(t) = r_i(s_i(t), a_i(t)), s(t + 1) from
            the agents' tables, t = 0 .. T;
    critic  Q^_i from 0: for t = 1 .. T, Q^_i(z_i(t - 1)) <- (1 - alpha_{t-1}) Q^_i(z_i(t - 1)) + alpha_{t-1}
            (r_i(t - 1) + gamma Q^_i(z_i(t))), z_i(t) = (s, a)_N_i^kappa(t), alpha_t = h / (t + t0);
    actor   g_i = sum_t gamma^t (1/n) sum_{j in N_i^kappa} Q^_j(z_j(t)) grad log zeta_i(a_i(t) | s_N_i(t)),
            theta_i <- theta_i + eta_m n g_i, eta_m = eta / sqrt(m + 1) (n g_i: the step of the team's sum, theirs of
            its mean times n, so that a step's size does not fall as the network grows).

An agent's work a step is its kappa-hop neighbourhood's, not the network's: it reads its neighbours' states and
actions and the truncated values of the agents within kappa hops (what its links would carry). The objective is the
discounted return, (1/n) sum_i E sum_t gamma^t r_i(t) from the start; where the joint table can be built (a few
agents, `NetworkedMDP.joint`) every checkpoint measures the exact normalised J_gamma of the current policies, else
the episodes' own discounted returns estimate it, with their standard error.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from dgtd.algorithms.actor import SoftmaxActor, actor_increment, policy
from dgtd.errors import DgtdInputError
from dgtd.problems import team
from dgtd.problems.networked import NetworkedMDP, hood_index
from dgtd.streams import ACTION, AGENT_START, seed_keys, singles, uniforms


@dataclass(frozen=True)
class ScalableSteps:
    """``kappa`` the critics' hops; ``horizon`` T; the critic's steps alpha_t = ``critic_step`` / (t +
    ``critic_offset``) and the actor's eta_m = ``actor_step`` / sqrt(m + 1) (Qu et al.'s forms)."""

    kappa: int = 1
    horizon: int = 10
    critic_step: float = 1.0
    critic_offset: float = 1.0
    actor_step: float = 1.0

    def __post_init__(self):
        if int(self.kappa) < 0 or int(self.horizon) < 1:
            raise DgtdInputError(f"kappa >= 0 and a horizon >= 1, got {self.kappa} and {self.horizon}")
        if not all(np.isfinite(x) and x > 0 for x in (self.critic_step, self.critic_offset, self.actor_step)):
            raise DgtdInputError("the scalable actor-critic's steps and offset must be numbers > 0")


def kappa_hoods(mdp: NetworkedMDP, kappa: int) -> np.ndarray:
    """(N, K) each agent's kappa-hop neighbourhood (the agent first, then the others ascending), padded with -1."""
    reach = [{i} for i in range(mdp.n_agents)]
    for _ in range(kappa):
        reach = [r | {int(j) for k in r for j in mdp.neighbourhoods[k] if j >= 0} for r in reach]
    K = max(len(r) for r in reach)
    out = np.full((mdp.n_agents, K), -1, dtype=np.int64)
    for i, r in enumerate(reach):
        row = [i, *sorted(r - {i})]
        out[i, : len(row)] = row
    return out


def pair_index(hoods: np.ndarray, s: np.ndarray, a: np.ndarray, S: int, A: int) -> np.ndarray:
    """(B, N): each agent's index of its neighbourhood's (state, action) pairs, the first member the most
    significant, in every agent's states and actions (B, N): `hood_index` of the digits s A + a."""
    return hood_index(hoods, s * A + a, S * A)


def learn_scalable(mdp: NetworkedMDP, steps: ScalableSteps, iterations: int, seeds: int = 2, seed: int = 0,
                   checkpoints: int = 20) -> dict:  # fmt: skip
    """Algorithm 1 of the module's docstring for ``iterations`` episodes: {"iterations" (C,), "return" (C, B) the
    exact normalised J_gamma of the policies at each checkpoint (NaN where the joint table is too large),
    "episode_return" (C, B) the mean normalised discounted team return of the episodes since the last checkpoint,
    "policies" (B, N, S^K, A), "seconds"}."""
    N, S, A = mdp.n_agents, mdp.n_states, mdp.n_actions
    hoods = kappa_hoods(mdp, steps.kappa)
    theta = np.zeros((seeds, N, S ** mdp.neighbourhoods.shape[1], A))
    keys, started = seed_keys(seed, range(seeds)), time.perf_counter()
    at = np.unique(np.linspace(0, iterations, checkpoints + 1).round().astype(int)[1:])
    exact = mdp.has_joint
    out = {name: np.full((len(at), seeds), np.nan) for name in ("return", "episode_return")}
    tally = np.zeros(seeds)
    for m in range(iterations):
        states, actions, rewards = _episode(mdp, theta, keys, m, steps.horizon)
        q = _critic(mdp, hoods, states, actions, rewards, steps)  # (T + 1, B, N): Q^_j(z_j(t)) at the episode's end
        for t, r in enumerate(rewards):  # (a step at a time: each seed's sum in the same order for any seeds)
            tally += mdp.gamma**t * r.mean(axis=1)
        theta = theta + steps.actor_step / np.sqrt(m + 1) * _gradient(mdp, hoods, theta, states, actions, q)
        if m + 1 in at:
            c = int(np.searchsorted(at, m + 1))
            episodes = m + 1 - (at[c - 1] if c else 0)
            out["episode_return"][c] = (1 - mdp.gamma) * tally / episodes
            tally[:] = 0.0
            if exact:
                out["return"][c] = [exact_return(mdp, policy(theta[b])) for b in range(seeds)]
    return {"iterations": at, **out, "policies": policy(theta), "seconds": time.perf_counter() - started}


def exact_return(mdp: NetworkedMDP, policies) -> float:
    """J_gamma of the local policies (N, S^K, A) from the joint table: (1 - gamma) start^T (I - gamma P_pi)^-1 rbar."""
    own = [p[: mdp.n_states ** int(m)] for p, m in zip(policies, mdp.sizes)]
    joint = mdp.joint(own)
    return team.discounted_return(joint, list(joint.policies or ()))


def _episode(mdp: NetworkedMDP, theta: np.ndarray, keys: np.ndarray, m: int, T: int) -> tuple:
    """Episode m: (states, actions, rewards), each (T + 1, B, N)."""
    B, N = theta.shape[:2]
    every = np.arange(N)
    s = team.draw(np.cumsum(mdp.start)[None, None, :], uniforms(keys[:, None], AGENT_START, m, every)[0])
    samples, actor = [], SoftmaxActor()
    for t in range(T + 1):
        k = m * (T + 1) + t
        pi = actor.probabilities(theta, mdp.local_index(s, every))  # (B, N, A): each at its neighbourhood's state
        a = team.draw(np.cumsum(pi, axis=-1), singles(keys[:, None], ACTION, k, every))
        s_next, r = mdp.step(s, a, keys, k)
        samples.append((s, a, r))
        s = s_next
    return tuple(np.stack(x) for x in zip(*samples))


def _critic(mdp: NetworkedMDP, hoods, states, actions, rewards, steps: ScalableSteps) -> np.ndarray:
    """Every agent's truncated critic learnt along the episode by TD(0) from 0; returns Q^_j^T(z_j(t)) (T + 1, B, N)."""
    T1, B, N = states.shape
    S, A = mdp.n_states, mdp.n_actions
    z = np.stack([pair_index(hoods, states[t], actions[t], S, A) for t in range(T1)])  # (T + 1, B, N)
    Q = np.zeros((B, N, (S * A) ** hoods.shape[1]))
    b, i = np.arange(B)[:, None], np.arange(N)[None, :]
    for t in range(1, T1):
        alpha = steps.critic_step / (t - 1 + steps.critic_offset)
        target = rewards[t - 1] + mdp.gamma * Q[b, i, z[t]]
        Q[b, i, z[t - 1]] += alpha * (target - Q[b, i, z[t - 1]])
    return np.stack([Q[b, i, z[t]] for t in range(T1)])


def _gradient(mdp: NetworkedMDP, hoods, theta, states, actions, q) -> np.ndarray:
    """n g_i = sum_t gamma^t sum_{j in N_i^kappa} Q^_j(z_j(t)) grad log zeta_i(a_i(t) | s_N_i(t)): the gradient of
    the team's sum of returns, n times that of their mean, so that an agent's step does not shrink as n grows."""
    N, valid = mdp.n_agents, hoods >= 0
    into = np.zeros_like(theta)
    every = np.arange(N)
    for t in range(states.shape[0]):
        shared = np.where(valid, q[t][:, np.maximum(hoods, 0)], 0.0).sum(axis=-1)  # (B, N): n times theirs
        weight = mdp.gamma**t * shared
        actor_increment(theta, mdp.local_index(states[t], every), actions[t], weight, 1.0, into)
    return into
