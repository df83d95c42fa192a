"""Chen, Zhou, Chen and Zou (ICML 2022), "Sample and communication-efficient decentralized actor-critic algorithms",
Algorithm 1 (decentralised actor-critic with mini-batches), as their code gives it (zuopaoyoutao/MACE at e568715,
`DAC`), for B seeds at once on a team MDP under the discounted objective.

An iteration t of the current policies pi_t (sample i counts every transition drawn, the key of its numbers):

    critic  T_c mini-batches of N_c transitions (s, a, s') of the chain under pi_t, each agent's own reward r_m, then
            Theta <- W Theta + (beta / N_c) sum_batch phi(s) (r_m + gamma phi(s')^T theta_m - phi(s)^T theta_m)
            (one consensus round a mini-batch, the TD step at the mini-batch's Theta), and T_c' rounds after: Theta
            <- W^T_c' Theta (their `DTD`; warm-started from the last iteration's);
    actor   N samples (s, a, s') with s from the discounted visitation chain P_xi = gamma P + (1 - gamma) xi (a
            restart from the start distribution xi with probability 1 - gamma at each step), s' ~ P(s, a, .); the
            team's reward by T_r consensus rounds of the sampled rewards, rhat = W^T_r r (their `Wpow_reward`); then
            omega_m <- omega_m + (alpha / N) sum_batch (rhat_m + gamma phi(s')^T theta_m - phi(s)^T theta_m)
            psi_m(s, a_m).

W is dgtd's Metropolis mixing of the fixed graph (theirs: 0.4 on the diagonal, 0.3 to each ring neighbour; both
doubly stochastic). Their s_{i+1} ~ P_xi is drawn apart from s'; here the chain's next state is s' itself unless it
restarts (the same marginals). The critic's chain goes on from where the last iteration left it (theirs restarts at
state 0). Their reward noise (multiplicative, t-distributed) is not drawn: the rewards are the model's means. J is
the normalised discounted return from xi, (1 - gamma) xi^T (I - gamma P_pi)^-1 rbar_pi, theirs exactly.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from dgtd.algorithms.actor import SoftmaxActor, actor_increment, policy
from dgtd.channels.base import BITS_PER_NUMBER
from dgtd.channels.perfect import mean_metropolis
from dgtd.errors import DgtdInputError
from dgtd.problems import team
from dgtd.run.learn import METRICS, LearnResult, measure
from dgtd.sources.team_env import BLOCK, ModelEnv
from dgtd.streams import ACTION, DISCOUNTED_RESTART, seed_keys, singles, uniforms


@dataclass(frozen=True)
class ChenSteps:
    """Algorithm 1's sizes and steps (their defaults: the 6-agent setting's N = 2 000 run): ``batch`` N actor samples an
    iteration, ``critic_batches`` T_c mini-batches of ``critic_batch`` N_c transitions, ``critic_rounds`` T_c'
    consensus rounds after them, ``reward_rounds`` T_r rounds on each sampled reward, ``actor_step`` alpha (the actor
    moves alpha / N times the batch's sum) and ``critic_step`` beta."""

    batch: int = 2000
    critic_batches: int = 50
    critic_batch: int = 10
    critic_rounds: int = 10
    reward_rounds: int = 5
    actor_step: float = 200.0
    critic_step: float = 0.5

    def __post_init__(self):
        for name in ("batch", "critic_batches", "critic_batch"):
            if int(getattr(self, name)) < 1:
                raise DgtdInputError(f"Chen et al.'s {name.replace('_', ' ')} must be >= 1, got {getattr(self, name)}")
        for name in ("critic_rounds", "reward_rounds"):
            if int(getattr(self, name)) < 0:
                raise DgtdInputError(f"Chen et al.'s {name.replace('_', ' ')} must be >= 0, got {getattr(self, name)}")
        for name in ("actor_step", "critic_step"):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise DgtdInputError(f"Chen et al.'s {name.replace('_', ' ')} must be > 0, got {getattr(self, name)}")

    @property
    def samples(self) -> int:
        """Transitions drawn an iteration: the critic's T_c N_c and the actor's N."""
        return self.critic_batches * self.critic_batch + self.batch


def mixing(network) -> sp.csr_matrix:
    """W (N, N): the Metropolis mixing of a fixed graph, 1 / (1 + max(d_i, d_j)) on each edge, the rest on the
    diagonal (symmetric and doubly stochastic): I less the channels' own mean Metropolis Laplacian, exact here."""
    if not network.fixed:
        raise DgtdInputError(
            "Chen et al.'s Algorithm 1 mixes over a fixed graph (their W): give --edge-prob 1 (each link always up)"
        )
    return (sp.identity(network.n_nodes, format="csr") - mean_metropolis(network, sparse=True)).tocsr()


def mixed(W: sp.csr_matrix, x: np.ndarray, rounds: int) -> np.ndarray:
    """W^rounds applied along x's agents axis (axis 1 of (B, N, ...)): ``rounds`` consensus rounds."""
    B, N = x.shape[:2]
    y = np.moveaxis(x, 1, 0).reshape(N, -1)
    for _ in range(rounds):
        y = W @ y
    return np.moveaxis(y.reshape((N, B) + x.shape[2:]), 0, 1)


class Sampler:
    """The transitions of B seeds' chains on ``mdp`` under the current policies, each keyed by its sample number (a
    block of `BLOCK` samples' numbers drawn at once, as `dgtd.run.learn` draws them)."""

    def __init__(self, mdp, keys: np.ndarray):
        self.mdp, self.keys, self.env = mdp, keys, ModelEnv(mdp, keys)
        self.start_cdf, self.top = np.cumsum(mdp.start), np.asarray(mdp.actions) - 1
        self._block: tuple = (-1, None, None)  # (a block's first sample, its actions' uniforms, its restarts')

    def _numbers(self, i: int) -> tuple:
        first = i - i % BLOCK
        if self._block[0] != first:
            k = np.arange(first, first + BLOCK, dtype=np.uint64)
            action = singles(self.keys[None, :, None], ACTION, k[:, None, None], np.arange(self.mdp.n_agents))
            self._block = (first, action, uniforms(self.keys[None, :], DISCOUNTED_RESTART, k[:, None], 0))
        return self._block[1][i - first], (self._block[2][0][i - first], self._block[2][1][i - first])

    def act(self, pi: np.ndarray, s: np.ndarray, i: int) -> np.ndarray:
        """Every agent's action (B, N) at states ``s`` (B,) under ``pi`` (B, N, S, A), drawn by sample i's numbers."""
        B, N = pi.shape[:2]
        rows = pi[np.arange(B)[:, None], np.arange(N)[None, :], s[:, None]]  # (B, N, A)
        return np.minimum(team.draw(np.cumsum(rows, axis=-1), self._numbers(i)[0]), self.top)

    def restarts(self, s_next: np.ndarray, i: int) -> np.ndarray:
        """The discounted visitation chain's next state: a draw from the start with probability 1 - gamma, else s'."""
        u, v = self._numbers(i)[1]
        return np.where(u < 1.0 - self.mdp.gamma, team.draw(self.start_cdf[None, :], v), s_next)


def learn_chen(mdp, network, steps: ChenSteps, settings, progress=None, on_measured=None) -> LearnResult:
    """Algorithm 1 (the module's docstring) on the team MDP ``mdp`` over ``network`` (fixed), ``settings`` a
    `dgtd.run.learn.LearnSettings` (its iterations the samples to draw in all, its seeds, seed, checkpoints;
    objective discounted), starting from the MDP's policies (uniform where it has none). ``progress(n)`` is called
    with the samples of each iteration, ``on_measured(steps, metrics)`` at each checkpoint."""
    if settings.objective != "discounted":
        raise DgtdInputError("Chen et al.'s Algorithm 1 ascends the discounted return: give --objective discounted")
    W, started = mixing(network), time.perf_counter()
    iterations = settings.iterations // steps.samples
    if iterations < 1:
        raise DgtdInputError(
            f"-T {settings.iterations} samples are fewer than one iteration of Algorithm 1 ({steps.samples}: "
            f"{steps.critic_batches} x {steps.critic_batch} for the critic, {steps.batch} for the actor)"
        )
    B, keys = settings.seeds, seed_keys(settings.seed, range(settings.seeds))
    sampler, actor = Sampler(mdp, keys), SoftmaxActor()
    theta = ModelEnv(mdp, keys).theta(actor, B)  # (B, N, S, A): omega
    critic = np.zeros((B, mdp.n_agents, mdp.n_features))  # Theta
    at = np.unique(np.linspace(0, iterations, settings.checkpoints + 1).round().astype(int)[1:])
    metrics = {name: np.full((len(at), B), np.nan) for name in METRICS}
    best = team.best_of(mdp, "discounted")
    s_critic = s_actor = team.draw(np.cumsum(mdp.start)[None, :], uniforms(keys, DISCOUNTED_RESTART, 0, 1)[0])
    i, E = 0, len(network.base.edges)
    for t in range(iterations):
        pi = policy(theta)
        critic, s_critic, i = _critic(sampler, W, steps, pi, critic, s_critic, i)
        increment, s_actor, i = _actor(sampler, W, steps, pi, theta, critic, s_actor, i)
        theta = theta + (steps.actor_step / steps.batch) * increment
        if progress is not None:
            progress(steps.samples)
        if t + 1 in at:
            c = int(np.searchsorted(at, t + 1))
            measure(mdp, theta, critic, metrics, c, settings, best[1])
            critic_rounds, reward_rounds = steps.critic_batches + steps.critic_rounds, steps.batch * steps.reward_rounds
            metrics["messages"][c] = 2 * E * (t + 1) * (critic_rounds + reward_rounds)  # (every arc, every round)
            metrics["bits"][c] = 2 * E * (t + 1) * (critic_rounds * mdp.n_features + reward_rounds) * BITS_PER_NUMBER
            if on_measured is not None:
                on_measured(at[: c + 1] * steps.samples, {k: v[: c + 1] for k, v in metrics.items()})
    info = {"objective": "discounted", "scheme": "chen", "backend": "numpy", "diverged_at": [-1] * B}
    return LearnResult(
        at * steps.samples, metrics, policy(theta), critic, best[0], best[1], metrics["messages"][-1],
        metrics["bits"][-1], time.perf_counter() - started, info,
    )  # fmt: skip


def _critic(sampler: Sampler, W, steps: ChenSteps, pi, critic, s, i: int) -> tuple:
    """The critic's T_c mini-batches and T_c' rounds of iteration t (their `DTD`): (Theta, the chain's state, i)."""
    Phi, gamma = sampler.mdp.Phi, sampler.mdp.gamma
    for _ in range(steps.critic_batches):
        direction = np.zeros_like(critic)
        for _ in range(steps.critic_batch):
            a = sampler.act(pi, s, i)
            step = sampler.env.step(s, a, i)
            delta = step.rewards + np.einsum("bq,bnq->bn", gamma * Phi[step.seen] - Phi[s], critic)
            direction += delta[:, :, None] * Phi[s][:, None, :]
            s, i = step.seen, i + 1
        critic = mixed(W, critic, 1) + (steps.critic_step / steps.critic_batch) * direction
    return mixed(W, critic, steps.critic_rounds), s, i


def _actor(sampler: Sampler, W, steps: ChenSteps, pi, theta, critic, s, i: int) -> tuple:
    """The actor's N samples of iteration t from the discounted visitation chain, their rewards mixed by T_r rounds:
    (the sum of their steps delta psi (theta's shape), the chain's state, i)."""
    Phi, gamma = sampler.mdp.Phi, sampler.mdp.gamma
    samples = []
    for _ in range(steps.batch):
        a = sampler.act(pi, s, i)
        step = sampler.env.step(s, a, i)
        samples.append((s, a, step.rewards, step.seen))
        s, i = sampler.restarts(step.seen, i), i + 1  # (a model's step: what the actors see next is s')
    states, actions, rewards, nexts = zip(*samples)
    here, after = Phi[np.stack(states)], Phi[np.stack(nexts)]  # (n, B, q)
    rhat = mixed(W, np.stack(rewards, axis=-1), steps.reward_rounds)  # (B, N, n): the team's reward, T_r rounds
    delta = rhat + np.einsum("nbq,bmq->bmn", gamma * after - here, critic)
    increment = np.zeros_like(theta)
    for j, (s_j, a_j) in enumerate(zip(states, actions)):
        actor_increment(theta, s_j, a_j, delta[:, :, j], 1.0, increment)
    return increment, s, i
