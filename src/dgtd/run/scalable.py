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
actions and the truncated values of the agents within kappa hops (what its links would carry). Over the ranks of an
mpiexec job (`dgtd.run.layout.learner_layout`) each rank holds its agents' actors and critics and draws their actions;
the actions of a step and the values of an episode are gathered in agent order (the joint step, cheap beside the
critics, is every rank's), so that every number is one process's, bit for bit. The objective is the
discounted return, (1/n) sum_i E sum_t gamma^t r_i(t) from the start; where the joint table can be built (a few
agents, `NetworkedMDP.joint`) every checkpoint measures the exact normalised J_gamma of the current policies, else
the episodes' own discounted returns estimate it, with their standard error.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass

import numpy as np

from dgtd.algorithms.actor import actor_increment, policy
from dgtd.errors import DgtdInputError
from dgtd.problems import team
from dgtd.problems.networked import NetworkedMDP, mixed_radix
from dgtd.run.layout import AllAgents
from dgtd.streams import ACTION, HOOD_LOSS, seed_keys, singles, uniforms


@dataclass(frozen=True)
class ScalableSteps:
    """``kappa`` the critics' hops; ``horizon`` T; the critic's steps alpha = ``critic_step`` / (tau - 1 +
    ``critic_offset``)^``critic_power`` at its t-th update of an episode (t = 1 .. T), tau = t, and the actor's eta_m =
    ``actor_step`` / sqrt(m + 1) (Qu et al.'s forms: each critic's table starts from 0 every episode). With
    ``restart`` R > 0 (their public code's form) each critic keeps its table over the episodes, and both steps start
    again every R episodes: tau = (m mod R) T + t, eta_m = ``actor_step`` / sqrt(m mod R + 1); with ``forget`` the
    tables start from 0 at each restart too, so that they hold at most R episodes' configurations (the memory of many
    agents: 24 users learn as well either way, docs/control.md)."""

    kappa: int = 1
    horizon: int = 10
    critic_step: float = 1.0
    critic_offset: float = 1.0
    actor_step: float = 1.0
    critic_power: float = 1.0
    restart: int = 0
    forget: bool = False

    def __post_init__(self):
        if int(self.kappa) < 0 or int(self.horizon) < 1 or int(self.restart) < 0:
            raise DgtdInputError(
                f"kappa >= 0, a horizon >= 1 and a restart >= 0, got {self.kappa}, {self.horizon}, {self.restart}"
            )
        steps = (self.critic_step, self.critic_offset, self.actor_step, self.critic_power)
        if not all(np.isfinite(x) and x > 0 for x in steps):
            raise DgtdInputError("the scalable actor-critic's steps, offset and power must be numbers > 0")

    def critic_rate(self, m: int, t: int) -> float:
        """alpha of the critic's t-th update of episode m."""
        tau = (m % self.restart) * self.horizon + t if self.restart else t
        return self.critic_step / (tau - 1 + self.critic_offset) ** self.critic_power

    def actor_rate(self, m: int) -> float:
        """eta_m of episode m."""
        return self.actor_step / np.sqrt((m % self.restart if self.restart else m) + 1)


def kappa_hoods(mdp, kappa: int) -> np.ndarray:
    """(N, K) each agent's kappa-hop neighbourhood (the agent first, then the others ascending), padded with -1."""
    reach, near = [{i} for i in range(mdp.n_agents)], mdp.neighbourhoods
    for _ in range(kappa):
        reach = [r | {int(j) for k in r for j in near[k] if j >= 0} for r in reach]
    K = max(len(r) for r in reach)
    out = np.full((mdp.n_agents, K), -1, dtype=np.int64)
    for i, r in enumerate(reach):
        row = [i, *sorted(r - {i})]
        out[i, : len(row)] = row
    return out


def own_actions(task) -> np.ndarray:
    """(N, A_max): whether each agent has each action (agents of fewer actions than the most)."""
    return np.arange(int(np.max(task.actions)))[None, :] < np.asarray(task.actions)[:, None]


def uniform_policies(task) -> np.ndarray:
    """(N, rows, A_max) each agent's uniform policy over its own actions, in every row."""
    have = own_actions(task).astype(np.float64)
    return np.repeat((have / have.sum(axis=1, keepdims=True))[:, None], task.observations, axis=1)


DENSE_MAX = 1 << 24  # numbers of the critics' dense tables (seeds x agents x (S A)^K) beyond which they are hashed
EVALUATION = 1 << 36  # the first episode number of the evaluation rollouts (their numbers apart from learning's)


class Critics:
    """Every agent's truncated critic Q^_i over its kappa-hop neighbourhood's (state, action) pairs (digit s A + a of
    each member, the agent's own the most significant: `dgtd.problems.networked.mixed_radix`), for B seeds: one
    dense table where (S A)^K is small (`DENSE_MAX`), else rows given to the configurations met
    (`dgtd.backends.compiled.table.FingerprintTable`); the same numbers either way. Where messages may be lost
    (``unheard``), a member not heard at a step is one more symbol of its digit."""

    def __init__(self, task, hoods: np.ndarray, seeds: int, unheard: bool = False):
        N, K = hoods.shape  # (the agents held here: a rank's, or every one)
        self.task, self.hoods, self.B = task, hoods, seeds
        self.base = task.state_values * int(np.max(task.actions)) + int(unheard)
        self.dense = seeds * N * float(self.base) ** K <= DENSE_MAX
        self.clear()

    def clear(self) -> None:
        """Every value 0 (a new episode, in the paper's form)."""
        N, K = self.hoods.shape
        if self.dense:
            self.values = np.zeros(self.B * N * self.base**K)
        else:
            from dgtd.backends.compiled.table import FingerprintTable

            self.table = FingerprintTable()

    def state(self) -> dict:
        """What a checkpoint keeps of the critics."""
        return {"values": self.values} if self.dense else {"table": self.table.state()}

    def restore(self, state: dict) -> None:
        if self.dense:
            self.values = np.array(state["values"], dtype=np.float64)
        else:
            from dgtd.backends.compiled.table import FingerprintTable

            self.table = FingerprintTable.restored(state["table"])
            self.values = self.table.values

    def rows(self, states: np.ndarray, actions: np.ndarray, heard=None) -> np.ndarray:
        """(T + 1, B, n): each agent's row of its neighbourhood's configuration at each step of an episode, from every
        agent's ``states`` and ``actions`` (T + 1, B, N); ``heard`` (T + 1, B, n, K) whether it heard each member's
        state and action (None: every one)."""
        B, n = states.shape[1], self.hoods.shape[0]
        owner = np.arange(B)[:, None] * n + np.arange(n)[None, :]  # (B, n): the agents held here
        digits = states * int(np.max(self.task.actions)) + actions  # (T + 1, B, N)
        valid = self.hoods >= 0
        members = np.where(valid, digits[..., np.maximum(self.hoods, 0)], -1)  # (T + 1, B, N, K)
        if heard is not None:
            members = np.where(heard | ~valid, members, self.base - 1)  # (the symbol of a member not heard)
        if self.dense:
            return owner * self.base ** self.hoods.shape[1] + mixed_radix(members, valid, self.base)
        from dgtd.backends.compiled.table import fingerprints

        rows = self.table.rows(fingerprints(owner, members))
        self.values = self.table.values
        return rows


def learn_scalable(task, steps: ScalableSteps, iterations: int, seeds: int = 2, seed: int = 0,
                   checkpoints: int = 20, evaluate: int = 0, progress=None, loss: float = 0.0,
                   on_measured=None, checkpoint_every: int = 0, on_checkpoint=None,
                   resume: dict | None = None, layout=None) -> dict:  # fmt: skip
    """Algorithm 1 of the module's docstring for ``iterations`` episodes on ``task`` (a `NetworkedMDP`, or any task
    of its form: `dgtd.problems.wireless.WirelessAccess`): {"iterations" (C,), "return" (C, B) the exact normalised
    J_gamma of the policies at each checkpoint (NaN where there is no joint table), "episode_return" (C, B) the mean
    normalised discounted team return of the episodes since the last checkpoint, "evaluated" (C, B) with ``evaluate``
    > 0 the mean of (1/n) sum_i sum_{t<T} gamma^t r_i(t) over that many rollouts of the policies at each checkpoint
    (`rollout_return`; Qu et al.'s measure), "policies" (B, N, rows, A; over ranks, on rank 0 alone), "seconds"}.
    With ``loss`` > 0 each message an agent needs from another within kappa hops is lost with that probability
    (`heard`): a member's state and action not heard at a step is a symbol of its own in the critic's configuration,
    a value not heard is left out of the actor's sum. ``on_measured(episodes, evaluated)`` is called at each
    checkpoint with the episodes so far (c,) and the evaluated returns there (c, B), so that what was measured is kept
    if the run is cut off. Every ``checkpoint_every`` episodes ``on_checkpoint(snapshot)`` gets the run's state;
    ``resume`` (one) continues from it to the uninterrupted run's numbers, bit for bit (every number is keyed by its
    episode). ``layout``: where the agents are held (`dgtd.run.layout.learner_layout`; None: all here)."""
    if not 0.0 <= loss < 1.0:
        raise DgtdInputError(f"the messages' loss probability is in [0, 1), got {loss}")
    layout = AllAgents(task.n_agents) if layout is None else layout
    own, A = layout.local, int(np.max(task.actions))
    hoods = kappa_hoods(task, steps.kappa)[own]
    theta = np.where(own_actions(task)[None, own, None, :], 0.0, -np.inf)  # (uniform policies)
    theta = np.broadcast_to(theta, (seeds, len(own), task.observations, A)).copy()
    keys, started = seed_keys(seed, range(seeds)), time.perf_counter()
    at = np.unique(np.linspace(0, iterations, checkpoints + 1).round().astype(int)[1:])
    exact = getattr(task, "has_joint", False)
    out = {name: np.full((len(at), seeds), np.nan) for name in ("return", "episode_return", "evaluated")}
    tally, critics, first = np.zeros(seeds), Critics(task, hoods, seeds, unheard=loss > 0), 0
    if resume is not None:
        first, theta, tally = int(resume["m"]), np.array(resume["theta"]), np.array(resume["tally"])
        out = {name: np.array(v) for name, v in resume["out"].items()}
        critics.restore(resume["critics"])
    for m in range(first, iterations):
        states, actions, rewards = _rollout(task, np.cumsum(policy(theta), axis=-1), keys, m, steps.horizon, layout)
        pairs, values = heard(hoods, keys, m, steps.horizon, loss, own)
        q = _critic(critics, states, actions, rewards[..., own], steps, m, pairs)  # (T + 1, B, n): Q^_j(z_j(t))
        for t, r in enumerate(rewards):  # (a step at a time: each seed's sum in the same order for any seeds)
            tally += task.gamma**t * r.mean(axis=1)
        every = np.moveaxis(layout.gather(np.moveaxis(q, 2, 1)), 1, 2)  # (T + 1, B, N): what the links would carry
        theta = theta + steps.actor_rate(m) * _gradient(task, hoods, theta, states, actions, every, values, own)
        if m + 1 in at:
            c = int(np.searchsorted(at, m + 1))
            episodes = m + 1 - (at[c - 1] if c else 0)
            out["episode_return"][c] = (1 - task.gamma) * tally / episodes
            tally[:] = 0.0
            if exact:
                whole = layout.gather(policy(theta))
                out["return"][c] = [exact_return(task, whole[b]) for b in range(seeds)]
            if evaluate:
                out["evaluated"][c] = rollout_return(task, policy(theta), keys, evaluate, steps.horizon, c, layout)
            if on_measured is not None:
                on_measured(at[: c + 1], out["evaluated"][: c + 1])
        if checkpoint_every and (m + 1) % checkpoint_every == 0 and on_checkpoint is not None:
            state = {"m": m + 1, "theta": theta, "tally": tally, "out": out, "critics": critics.state()}
            on_checkpoint(copy.deepcopy(state))  # (copies: the run goes on changing its arrays in place)
        if progress is not None:
            progress(1)
    policies = layout.gather_root(policy(theta))
    return {"iterations": at, **out, "policies": policies, "seconds": time.perf_counter() - started}


def exact_return(mdp: NetworkedMDP, policies) -> float:
    """J_gamma of the local policies (N, S^K, A) from the joint table: (1 - gamma) start^T (I - gamma P_pi)^-1 rbar."""
    own = [p[: mdp.n_states ** int(m)] for p, m in zip(policies, mdp.sizes)]
    joint = mdp.joint(own)
    return team.discounted_return(joint, list(joint.policies or ()))


def rollout_return(task, policies: np.ndarray, keys: np.ndarray, episodes: int, T: int, at: int = 0,
                   layout=None) -> np.ndarray:  # fmt: skip
    """(B,) the mean over ``episodes`` rollouts of (1/n) sum_i sum_{t<T} gamma^t r_i(t) under ``policies`` (B, n,
    rows, A) (or one set (n, rows, A) for every seed) of the agents ``layout`` holds (None: all of them), each
    rollout's numbers keyed by its own episode number (from `EVALUATION` + ``at`` x ``episodes``: apart from
    learning's, the same for every policy evaluated at ``at``)."""
    B = len(keys)
    policies = np.broadcast_to(policies, (B, *policies.shape[-3:]))
    cdf = np.cumsum(policies, axis=-1)
    total = np.zeros(B)
    for e in range(episodes):
        m = EVALUATION + at * episodes + e
        states, actions, rewards = _rollout(task, cdf, keys, m, T, layout)
        total += sum(task.gamma**t * r.mean(axis=1) for t, r in enumerate(rewards[:T]))
    return total / episodes


def _rollout(task, cdf: np.ndarray, keys: np.ndarray, m: int, T: int, layout=None) -> tuple:
    """Episode m of T + 1 steps under the policies' cumulative tables ``cdf`` (B, n, rows, A) of the agents
    ``layout`` holds (None: all): step k = m (T + 1) + t, each agent's action by its own number (ACTION, k, agent),
    every agent's gathered; (states, actions, rewards), each (T + 1, B, N), every agent's."""
    layout = AllAgents(task.n_agents) if layout is None else layout
    B, own = cdf.shape[0], layout.local
    b, i = np.arange(B)[:, None], np.arange(len(own))[None, :]
    s = task.first_states(keys, m)
    samples = []
    for t in range(T + 1):
        k = m * (T + 1) + t
        mine = team.draw(cdf[b, i, task.observe(s)[:, own]], singles(keys[:, None], ACTION, k, own))
        a = layout.gather(mine)
        s_next, r = task.step(s, a, keys, k)
        samples.append((s, a, r))
        s = s_next
    return tuple(np.stack(x) for x in zip(*samples))


def heard(hoods: np.ndarray, keys: np.ndarray, m: int, T: int, loss: float, agents=None) -> tuple:
    """(states and actions, values) each (T + 1, B, n, K) or None where nothing is lost: whether agent i (of
    ``agents``, the rows of ``hoods``; None: every agent) heard at
    step t of episode m the member in slot s of its kappa-hop neighbourhood (itself always), each message lost with
    probability ``loss`` by its own number (HOOD_LOSS, step, entity i, index s: u0 the state and action, u1 the
    value)."""
    if not loss:
        return None, None
    N, K = hoods.shape
    agents = np.arange(N) if agents is None else agents
    k = m * (T + 1) + np.arange(T + 1)
    u = uniforms(keys[None, :, None, None], HOOD_LOSS, k[:, None, None, None], agents[:, None], np.arange(K))
    own = np.arange(K) == 0  # (slot 0: the agent itself)
    return tuple((x >= loss) | own for x in u)


def _critic(critics: Critics, states, actions, rewards, steps: ScalableSteps, m: int, heard=None) -> np.ndarray:
    """Every agent's truncated critic moved along episode m by TD(0) (from 0 in the paper's form, else from what it
    learnt before: ``steps.restart``); returns Q^_j(z_j(t)) (T + 1, B, N) at the episode's end."""
    if not steps.restart or (steps.forget and m % steps.restart == 0):
        critics.clear()
    z = critics.rows(states, actions, heard)  # (T + 1, B, N)
    Q, gamma = critics.values, critics.task.gamma
    for t in range(1, z.shape[0]):  # (one agent's rows are its own: no two agents of a step share one)
        target = rewards[t - 1] + gamma * Q[z[t]]
        Q[z[t - 1]] += steps.critic_rate(m, t) * (target - Q[z[t - 1]])
    return Q[z]


def _gradient(task, hoods, theta, states, actions, q, heard=None, agents=None) -> np.ndarray:
    """n g_i = sum_t gamma^t sum_{j in N_i^kappa} Q^_j(z_j(t)) grad log zeta_i(a_i(t) | o_i(t)): the gradient of
    the team's sum of returns, n times that of their mean, so that an agent's step does not shrink as n grows (the
    values ``heard`` (T + 1, B, n, K) alone, where messages may be lost), for the agents ``agents`` (the rows of
    ``hoods`` and ``theta``; None: every agent) from every agent's states, actions and values ``q`` (T + 1, B, N)."""
    agents = slice(None) if agents is None else agents
    valid = hoods >= 0
    into = np.zeros_like(theta)
    for t in range(states.shape[0]):
        kept = valid if heard is None else valid & heard[t]
        shared = np.where(kept, q[t][:, np.maximum(hoods, 0)], 0.0).sum(axis=-1)  # (B, N): n times theirs
        actor_increment(
            theta, task.observe(states[t])[:, agents], actions[t][:, agents], task.gamma**t * shared, 1.0, into
        )
    return into
