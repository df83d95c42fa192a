"""Agents that learn their policies in a simulator, a PettingZoo ParallelEnv (`dgtd learn mpe-spread`, or a user's
env through `learn_env`), where there is no model to solve.

Each agent's actor is a softmax linear in features of its own observation (`dgtd.algorithms.actor.LinearSoftmaxActor`,
with the steps of the `SoftmaxActor` given): pi_i(a | o_i) = exp(theta_i[a] . x_i) / sum_b exp(theta_i[b] . x_i),
x_i = (o_i, 1). Everything else is `dgtd.run.learn`'s step on a model: the actions drawn
from the keyed streams (purpose ACTION), the critics on features phi(s) of the env's global state (its own reward, or
the team's for centralised actors; differential under the average objective, discounted by the task's gamma under the
discounted one: `dgtd.run.learn.objective_terms`), the networked agents' consensus estimate of the team's reward on
f(s, a) = (phi(s) e_{a_1}^T, ..., phi(s) e_{a_N}^T) (additive over the agents, as on a model), the same links and
`round_end`. A time limit is not terminal: the TD target bootstraps from the state reached.

Without a model the return is estimated: at each checkpoint, the team's mean reward per step over the interval since
the last one (each seed's; `LearnResult.metrics["return"]`), the team's mean return an episode over the episodes that
ended in it (``"episode_return"``: the sum of the team's mean reward over an episode, what shows learning in an
episodic task), and the mean entropy of the policies at the observations met. A simulator's state cannot be saved,
so these runs take no checkpoints to resume from.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from dgtd.algorithms.actor import LinearSoftmaxActor, SoftmaxActor, td_error, two_timescales
from dgtd.algorithms.stepsizes import step_sizes
from dgtd.algorithms.team_reward import regression_rate, regression_step
from dgtd.channels import Arcs, Perfect
from dgtd.errors import DgtdInputError
from dgtd.problems import team
from dgtd.run.layout import AllAgents
from dgtd.run.learn import METRICS, Learners, LearnPlan, LearnResult, LearnSettings, objective_terms, round_end
from dgtd.samples import Sample
from dgtd.streams import ACTION, EDGE_UP, seed_keys, singles


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


def learn_env(
    task: EnvTask, network, critic, actor: SoftmaxActor, settings: LearnSettings, channel=None, progress=None,
    on_measured=None,
):  # fmt: skip
    """Learners in ``task``'s simulator (the module's docstring); the arguments as `dgtd.run.learn.learn`'s (no
    checkpoints to resume from, the NumPy backend: the simulator's step is the cost)."""
    from dgtd.sources.env import EnvSource

    two_timescales(actor, critic)
    actor = LinearSoftmaxActor.like(actor)
    if settings.values != "state" or settings.batch != 1:
        raise DgtdInputError(
            "in a simulator the critics evaluate state values, a step at a time (no --values, --batch)"
        )
    src = EnvSource(
        task.make, task.features, settings.seed, range(settings.seeds), network=network, name=task.name,
        reward_map=task.reward_map,
    )  # fmt: skip
    src.start()
    agents, B = src.agents, settings.seeds
    N, A = len(agents), discrete_actions(src.spaces[0], src.name)
    if network.n_nodes != N or task.n_agents != N:
        raise DgtdInputError(f"the network has {network.n_nodes} agents, the env {N} (its task says {task.n_agents})")
    x = _observed(src, range(B))  # (B, N, d)
    q = src.features_of([src.current[0]]).shape[1]
    T = settings.iterations
    plan = LearnPlan(
        task, network, critic, actor, settings, channel if channel is not None else Perfect(),
        Arcs.of(network.base.edges, N), seed_keys(settings.seed, range(B)),
        step_sizes(critic.schedule, critic.alpha0, critic.beta, 0, T), actor.steps(0, T), np.zeros(T),
        np.unique(np.linspace(0, T, settings.checkpoints + 1).round().astype(int)[1:]), AllAgents(N),
    )  # fmt: skip
    run = Learners(
        0, np.zeros(B, np.int64), actor.init(B, [A] * N, x.shape[-1]),
        np.zeros((B, N, N * A * q)) if settings.actor == "networked" else None, critic.init(B, N, q),
        plan.channel.init(B, plan.arcs, settings.seed),
        {name: np.full((B, len(plan.at)), np.nan) for name in (*METRICS, "episode_return")},
        means=np.zeros((B, N, 2)) if settings.objective == "average" else None,
    )  # fmt: skip
    # per seed, since the last checkpoint: team reward, entropy, steps, the episodes' team returns, episodes ended;
    # and the team's return of the episode under way
    started, tally, episode = time.perf_counter(), np.zeros((B, 5)), np.zeros(B)
    for k in range(T):
        episodes, reward = np.array(src.episodes), tally[:, 0].copy()
        x = _step(plan, run, src, x, k, q, tally)
        episode += tally[:, 0] - reward
        ended = np.array(src.episodes) > episodes  # (an episode ended at this step: the next began)
        tally[:, 3:] += np.stack([np.where(ended, episode, 0.0), ended], axis=1)
        episode[ended] = 0.0
        if k + 1 in plan.at:
            c = int(np.searchsorted(plan.at, k + 1))
            run.metrics["return"][:, c], run.metrics["entropy"][:, c] = (
                tally[:, 0] / tally[:, 2],
                tally[:, 1] / tally[:, 2],
            )
            with np.errstate(invalid="ignore", divide="ignore"):  # (no episode ended: NaN)
                run.metrics["episode_return"][:, c] = np.where(tally[:, 4] > 0, tally[:, 3] / tally[:, 4], np.nan)
            run.metrics["messages"][:, c], run.metrics["bits"][:, c] = run.links.messages, run.links.bits
            tally[:] = 0.0
            if on_measured is not None:
                on_measured(plan.at[: c + 1], {name: v[:, : c + 1] for name, v in run.metrics.items()})
        if progress is not None:
            progress(1)
    return LearnResult(
        plan.at, run.metrics, run.theta, critic.estimate(run.critic), None, None, run.links.messages, run.links.bits,
        time.perf_counter() - started,
        {"backend": "numpy", "agents": agents, "estimated": True, "objective": settings.objective},
    )  # fmt: skip


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


def _observed(src, seeds) -> np.ndarray:
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


def _step(plan: LearnPlan, run: Learners, src, x: np.ndarray, k: int, q: int, tally: np.ndarray) -> np.ndarray:
    """Step k of every seed (the module's docstring); returns the actors' features of the observations reached."""
    B, N, A, _ = run.theta.shape
    pi = plan.actor.probabilities(run.theta, x)  # (B, N, A)
    a = np.minimum(team.draw(np.cumsum(pi, axis=-1), singles(plan.keys[:, None], ACTION, k, np.arange(N))), A - 1)
    steps = [src.act(b, {agent: int(a[b, i]) for i, agent in enumerate(src.agents)}) for b in range(B)]
    phi = src.features_of([s[0] for s in steps] + [s[2] for s in steps])
    r, going = np.stack([s[1] for s in steps]), np.array([s[3] for s in steps], np.float64)  # (B, N), (B,)
    phi, phi_next = phi[:B, None, :], phi[B:, None, :]
    rbar = r.mean(axis=1, keepdims=True)
    own = np.broadcast_to(rbar, r.shape) if plan.settings.actor == "centralised" else r
    W = plan.critic.estimate(run.critic)
    rhat = own
    if run.lam is not None:  # lambda_i^T f(s, a): agent j's block at its action, times phi(s)
        lam = run.lam.reshape(B, N, N, A, q)
        picked = lam[
            np.arange(B)[:, None, None], np.arange(N)[None, :, None], np.arange(N)[None, None, :], a[:, None, :]
        ]
        rhat = (picked * phi[:, :, None, :]).sum(axis=(2, 3))  # (B, N)
        f = np.zeros((B, N, A, q))
        f[np.arange(B)[:, None], np.arange(N)[None, :], a] = phi  # (B, N, A, q): f(s, a) by blocks, g(s) = phi(s)
        nu = regression_rate(k, N, np.maximum((phi[:, 0] ** 2).sum(axis=1), 1e-12))  # (B,)
        run.pending["lam"] = regression_step(nu[:, None], r, rhat)[:, :, None] * f.reshape(B, 1, -1)
    reward, discount, baseline = objective_terms(plan, run, own, rhat, k)
    gamma = going[:, None] * discount  # (a terminal step's next state is not bootstrapped from)
    delta = td_error(rhat, baseline, gamma, (W * phi_next).sum(-1), (W * phi).sum(-1))
    d = plan.critic.directions(run.critic, Sample(phi, phi_next, reward, np.ones((B, 1)), gamma))
    run.pending["d"], run.pending["n"] = d, run.pending.get("n", 0) + 1
    run.pending["theta"] = plan.actor.increment(run.theta, x, a, delta, plan.betas[k])
    entropy = -(pi * np.log(np.where(pi > 0, pi, 1.0))).sum(axis=-1).mean(axis=1)
    tally[:, :3] += np.stack([rbar[:, 0], entropy, np.ones(B)], axis=1)
    run.k = k + 1
    up = (
        None
        if plan.network.fixed
        else singles(plan.keys[:, None], EDGE_UP, k, np.arange(plan.network.n_edges)) < plan.network.p
    )
    if plan.settings.actor == "independent":
        up = np.zeros((B, plan.network.n_edges), bool)  # they send nothing
    round_end(plan, run, up, k)
    return _observed(src, range(B))


def env_summary(result: LearnResult, task: EnvTask, record: dict) -> dict:
    """summary.json of learners in a simulator: what was asked and, per seed, the team's mean reward a step over the
    last interval (``return_last``, estimated: ``return_estimated``); no J* and no policy tables (no model)."""
    return {
        "task": task.name,
        "n_agents": task.n_agents,
        "agents": result.info["agents"],
        "gamma": task.gamma,
        "objective": result.info["objective"],
        "config": record,
        "return_estimated": True,
        "return_first": result.metrics["return"][:, 0].tolist(),
        "return_last": result.metrics["return"][:, -1].tolist(),
        "episode_return_first": _listed(result.metrics["episode_return"][:, 0]),
        "episode_return_last": _listed(result.metrics["episode_return"][:, -1]),
        "return_best": None,
        "entropy_last": result.metrics["entropy"][:, -1].tolist(),
        "messages": result.messages.tolist(),
        "bits": result.bits.tolist(),
        "seconds": result.seconds,
    }


def _listed(x: np.ndarray) -> list:
    """Numbers as JSON holds them: NaN (no episode ended in the interval) as null."""
    return [None if not np.isfinite(v) else float(v) for v in x]
