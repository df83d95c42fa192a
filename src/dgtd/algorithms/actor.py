"""Each agent's actor: a tabular softmax policy over its own actions, moved along its TD error times its score.

Agent i's policy is pi_i(a_i | s) = exp(theta_i[s, a_i]) / sum_b exp(theta_i[s, b]) (Zhang et al. 2018, section 3:
any policy differentiable in its parameters; the tabular softmax is their experiments' and every policy is one of
its limits). Its score is psi_i = grad log pi_i(a_i | s) = e_{s, a_i} - pi_i(. | s) on row s, and the actor step of
their Algorithm 2,

    theta_i <- theta_i + beta_k delta_i psi_i,

takes the TD error delta_i = rhat_i + gamma V(s'; w_i) - V(s; w_i) of agent i's critic w_i as its advantage (rhat_i
the team's reward as agent i knows it: `dgtd.run.learn`). Two timescales: the actor holds still for its first
``warmup`` steps while the critics learn the starting policies' values, then beta_k = step / (1 + k / offset)^power
with power in (1/2, 1], so that beta_k / alpha_k -> 0 for the critics' alpha_k = alpha0 / sqrt(k + beta): the critic
is the faster in the limit (`two_timescales` refuses steps where it is not, and `timescales` says up to which step
the actor's step is the larger). Borkar's two-timescale theorem (Borkar 1997; Zhang et al. 2018, Assumption 4.3) also
asks sum alpha_k^2 < infinity, which the critics' sqrt schedule does not meet (its harmonic one does, but then no
actor's steps fall faster and still sum to infinity): with alpha_k ~ k^-1/2 the critic's error falls in mean square,
not almost surely. Without the warm-up, a delayed reward is lost: on a task where two agents must advance together 4
times to earn 3 (else 0.3 a step), actors that move from the first step commit to the 0.3 before the critics have
seen the prize (J 0.30 of J* 0.75), and after 2 000 steps of warm-up reach 0.747 (`docs/control.md`). Agents and seeds
are array axes: theta is (B, N, S, A_max), an agent with fewer actions padded with -inf (probability 0, and its score
0 there).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from dgtd.errors import DgtdInputError
from dgtd.samples import added, namespace

FLOOR = 1e-6  # the least probability a starting policy's action keeps
WARMUP = 2000  # the actor's default warm-up: at most this many steps, and a tenth of the run
CRITIC_POWER = {"sqrt": 0.5, "harmonic": 1.0, "constant": 0.0}  # alpha_k's decay, k^-p, of the critics' schedules


@dataclass(frozen=True)
class SoftmaxActor:
    """``step``, ``offset`` and ``power`` of the actor's steps beta_k = step / (1 + k / offset)^power from step
    ``warmup`` on (0 before; None: `WARMUP` steps, at most a tenth of the run)."""

    step: float = 0.5
    offset: float = 1000.0
    power: float = 0.8
    warmup: int | None = None
    entropy: float = 0.0  # tau: the actors ascend J + tau H (their policies' entropy), `score_step`

    def __post_init__(self):
        if not (np.isfinite(self.step) and self.step > 0 and self.offset > 0 and 0.0 < self.power <= 1.0):
            raise DgtdInputError(
                f"the actor's steps step / (1 + k / offset)^power need step > 0, offset > 0 and power in (0, 1]; got "
                f"{self.step}, {self.offset}, {self.power}"
            )
        if not (np.isfinite(self.entropy) and self.entropy >= 0.0):
            raise DgtdInputError(f"the actors' entropy bonus is a number >= 0, got {self.entropy}")
        if self.warmup is not None and not (isinstance(self.warmup, int | np.integer) and self.warmup >= 0):
            raise DgtdInputError(f"the actor's warm-up is a number of steps >= 0, got {self.warmup!r}")

    def init(self, seeds: int, actions, states: int) -> np.ndarray:
        """theta (B, N, S, A_max): uniform policies; -inf where an agent has no such action."""
        actions = np.asarray(actions)
        theta = np.zeros((seeds, len(actions), states, int(actions.max())))
        absent = np.arange(theta.shape[-1])[None, :] >= actions[:, None]  # (N, A_max)
        theta[:, absent[:, None, :].repeat(states, axis=1)] = -np.inf
        return theta

    def starting_at(self, theta: np.ndarray, policies) -> np.ndarray:
        """theta whose policies are ``policies`` (each (S, A_i)): log pi, a probability below `FLOOR` raised to it (a
        softmax cannot leave 0: an action the starting policy never takes would never be tried)."""
        theta = theta.copy()
        for i, p in enumerate(policies):
            theta[:, i, :, : p.shape[1]] = np.log(np.maximum(p, FLOOR))[None]
        return theta

    def probabilities(self, theta: np.ndarray, s: np.ndarray) -> np.ndarray:
        """pi (B, n, A_max) of every agent of theta's at each seed's state ``s`` (B,), or at each agent's own row
        ``s`` (B, n) (an agent with local states: its neighbourhood's, `dgtd.problems.networked`)."""
        B, n = theta.shape[:2]
        return policy(theta[np.arange(B)[:, None], np.arange(n)[None, :], s[:, None] if s.ndim == 1 else s])

    def increment(self, theta, s, a, delta, beta: float, into=None) -> np.ndarray:
        """beta delta psi of one sample added to ``into`` (theta's shape; new where None): `actor_increment`."""
        return actor_increment(theta, s, a, delta, beta, into, self.entropy)

    def held_for(self, T: int) -> int:
        """The steps of a run of T for which the actor holds still."""
        return min(WARMUP, T // 10) if self.warmup is None else int(self.warmup)

    def steps(self, k0: int, k1: int, T: int | None = None) -> np.ndarray:
        """beta_k for k in [k0, k1) of a run of T steps (default k1): 0 during the warm-up (`held_for`)."""
        k = np.arange(k0, k1, dtype=np.float64)
        beta = self.step / (1.0 + k / self.offset) ** self.power
        return np.where(k < self.held_for(k1 if T is None else T), 0.0, beta)

    def describe(self, T: int | None = None) -> str:
        held = "" if T is None else f"still for {self.held_for(T):,} steps, then "
        bonus = f", entropy bonus {self.entropy:g}" if self.entropy else ""
        return f"softmax actors, {held}beta_k = {self.step:g}/(1+k/{self.offset:g})^{self.power:g}{bonus}"


def two_timescales(actor: SoftmaxActor, critic) -> None:
    """Refuse steps under which the critic is not the faster: beta_k / alpha_k must fall to 0."""
    p = CRITIC_POWER.get(getattr(critic, "schedule", "sqrt"), 0.5)
    if actor.power <= p:
        raise DgtdInputError(
            f"the actor's steps must fall faster than the critic's (two timescales, the critic the faster): the "
            f"critic's alpha_k falls as k^-{p:g}, the actor's as k^-{actor.power:g}; give --actor-power above {p:g}"
        )


def timescales(actor: SoftmaxActor, critic, T: int) -> str:
    """One line on the run's two timescales, or "" where the critic's step is the larger at every step the actor
    moves: the largest ratio beta_k / alpha_k and the step from which the critic's is the larger for good (found on a
    geometric grid to 10^13 steps, beyond the run where need be)."""
    from dgtd.algorithms.stepsizes import step_sizes

    two_timescales(actor, critic)  # (refused first: steps that never put the critic ahead)
    start = actor.held_for(T)
    k = np.unique(np.concatenate([np.arange(start, min(T, start + 4096)), np.geomspace(max(start, 1), 1e13, 4000)]))
    k = k[k >= start].astype(np.int64)
    ratio = np.array([actor.steps(int(x), int(x) + 1, T)[0] for x in k]) / np.array(
        [step_sizes(critic.schedule, critic.alpha0, critic.beta, int(x), int(x) + 1)[0] for x in k]
    )
    if ratio.max() <= 1.0:
        return ""
    faster = k[ratio > 1.0]
    return (
        f"the actor's step is up to {ratio.max():.3g} times the critic's after its warm-up, the larger until step "
        f"{int(faster.max()) + 1:,.3g} (beta_k / alpha_k -> 0): --actor-step, --actor-warmup or --alpha0 change it"
    )


def policy(theta: np.ndarray) -> np.ndarray:
    """pi (..., A_max) of theta (..., A_max): the softmax of each row, stable (its largest entry subtracted)."""
    z = namespace(theta).exp(theta - theta.max(axis=-1, keepdims=True))
    return z / z.sum(axis=-1, keepdims=True)


def td_error(reward, baseline, gamma, v_next, v_here):
    """delta = r - baseline + gamma V(s') - V(s), the TD error an actor takes as its advantage (Zhang et al. 2018,
    Algorithm 2's actor step): ``reward`` the team's reward as the agent knows it, ``baseline`` the average
    objective's running mean of it mu~ (0 for the discounted objective), ``gamma`` 1 under the average objective."""
    return reward - baseline + gamma * v_next - v_here


def score_step(beta, delta, log_pi, tau, taken, p):
    """One entry of the actor's step beta_k (delta - tau log pi(a)) psi on a softmax's logit of action c, psi's entry
    1{c = a} - pi(c) (``taken`` 1 where c is the action taken, ``p`` pi(c)): the advantage ``delta`` less the entropy
    bonus ``tau`` times ``log_pi`` of the action taken, whose mean over a ~ pi, times the score, is the gradient of
    J + tau H(pi(. | s)) (E[psi log pi] = -grad H). A linear softmax's weights move by it times their features; a
    tabular one's row of the state by it alone."""
    return beta * (delta - tau * log_pi) * (taken - p)


# td_error and score_step take scalars or arrays: the tabular and linear actors below, the model's and simulator's
# learners and the compiled ones (`dgtd.backends.compiled.learner`) run these definitions, JAX arrays as well.


def actor_increment(
    theta: np.ndarray, s: np.ndarray, a: np.ndarray, delta: np.ndarray, beta: float, into=None, tau: float = 0.0
):
    """beta delta psi, the actor step of one sample, added to ``into`` (a new zero array of theta's shape if None):
    row s_b of every agent of seed b gets `score_step` on each action, ``s`` (B,) (or each agent's own row, (B, N)),
    ``a`` and ``delta`` (B, N). An action an agent does not have (-inf) gets nothing. NumPy's ``into`` is added to in
    place; JAX's is returned new (`dgtd.samples.added`)."""
    xp = namespace(theta)
    B, N = a.shape
    b, i = np.arange(B)[:, None], np.arange(N)[None, :]
    s = s[:, None] if s.ndim == 1 else s
    rows = theta[b, i, s]  # (B, N, A_max)
    pi = policy(rows)
    log_pi = xp.log(pi[b, i, a])[:, :, None] if tau else 0.0  # (without a bonus, no 0 x log 0)
    taken = added(xp.zeros_like(pi), (b, i, a), 1.0)
    step = score_step(beta, delta[:, :, None], log_pi, tau, taken, pi)
    into = xp.zeros_like(theta) if into is None else into
    return added(into, (b, i, s), xp.where(xp.isfinite(rows), step, 0.0))


def own_values(W, agents: np.ndarray, s, n_states: int, n_actions: int):
    """Q_i(s, .) (B, n, A) of each agent i of ``agents`` (n,) under the action-value critic's additive features
    (`dgtd.run.learn`, Zhang et al.'s Algorithm 1): agent i's own block of its weights W (B, n, N S A) at each seed's
    state ``s`` (B,), w_i[i, s, .]."""
    at = (agents[None, :, None] * n_states + s[:, None, None]) * n_actions + np.arange(n_actions)
    return namespace(W).take_along_axis(W, at, axis=2)


def action_advantage(q, pi, a):
    """A_i = Q_i(s, a_i) - sum_c pi_i(c | s) Q_i(s, c) (B, n): ``q`` `own_values`, ``pi`` the agents' policies at s
    (B, n, A), ``a`` their actions (B, n); an action an agent does not have (probability 0) adds nothing."""
    xp = namespace(q)
    return xp.take_along_axis(q, a[:, :, None], axis=2)[:, :, 0] - (pi * xp.where(pi > 0, q, 0.0)).sum(-1)


@dataclass(frozen=True)
class LinearSoftmaxActor(SoftmaxActor):
    """A softmax linear in features of the agent's own observation, for a simulator (Zhang et al. 2018, section 3:
    any differentiable policy): pi_i(a | o_i) = exp(theta_i[a] . x_i) / sum_b exp(theta_i[b] . x_i), x_i = (o_i, 1),
    its score (e_a - pi_i(. | o_i)) x_i^T; theta (B, N, A, d). Its steps are `SoftmaxActor`'s."""

    @classmethod
    def like(cls, actor: SoftmaxActor) -> LinearSoftmaxActor:
        """The linear actor with ``actor``'s steps."""
        return cls(**{f.name: getattr(actor, f.name) for f in fields(SoftmaxActor)})

    def init(self, seeds: int, actions, states: int) -> np.ndarray:  # type: ignore[override]
        """theta (B, N, A, d) of zeros: uniform policies; ``actions`` (N,) the same for every agent, ``states`` d."""
        return np.zeros((seeds, len(actions), int(max(actions)), states))

    def probabilities(self, theta: np.ndarray, x: np.ndarray) -> np.ndarray:
        """pi (B, N, A) at the features ``x`` (B, N, d) of each agent's observation."""
        return policy(np.einsum("bnad,bnd->bna", theta, x))

    def increment(self, theta, x, a, delta, beta: float, into=None) -> np.ndarray:
        """beta delta psi of one sample added to ``into`` (B, N, A, d; new where None): `score_step` on each action
        times the features ``x``."""
        pi = self.probabilities(theta, x)
        taken = np.eye(pi.shape[-1])[a]
        log_pi = np.log(np.take_along_axis(pi, a[:, :, None], axis=2)) if self.entropy else 0.0
        step = score_step(beta, delta[:, :, None], log_pi, self.entropy, taken, pi)[..., None] * x[:, :, None, :]
        return step if into is None else into + step
