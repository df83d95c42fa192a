"""Multi-agent MDPs whose agents learn their policies (`dgtd learn`), and the exact answers a learning run is measured
against.

A team MDP (the setting of the paper's section 3, the policy no longer fixed): S states every agent observes; agent i
takes a_i in {0, ..., A_i - 1} by its own policy pi_i(a_i | s); the joint action a = (a_1, ..., a_N), flattened in C
order, moves the state by P(s, a, s') and pays agent i its local reward R_i(s, a). The team is scored on the average of
the local rewards, rbar(s, a) = (1/N) sum_i R_i(s, a), which no agent sees.

The objective is the long-run average team reward (Zhang, Yang, Liu, Zhang and Basar, "Fully decentralized
multi-agent reinforcement learning with networked agents", ICML 2018, section 2, the objective J(theta) their actors
ascend):

    J(pi) = sum_s d_pi(s) sum_a pi(a | s) rbar(s, a),     d_pi the stationary distribution of P_pi,

computed here by linear algebra on the model (`average_return`), and its maximum over joint policies J* by relative
value iteration over the joint actions (`best_return`: exact to 1e-10 where S x A fits). The other objective a run
may choose is the normalised discounted return from the start, J_gamma(pi) = (1 - gamma) start^T (I - gamma
P_pi)^-1 rbar_pi (`discounted_return`), its maximum by value iteration (``best_discounted``). The critics evaluate
the differential (average objective) or discounted value of the team reward, V_pi = Phi w; their fixed point under
the current policy, w*(pi), is the exact one of the paper's section 6 on the Markov reward process (P_pi, R_pi)
(`critic_target`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from dgtd.errors import DgtdInputError
from dgtd.problems.model import check_stochastic

JOINT_LIMIT = 1 << 20  # states x joint actions beyond which no joint table is built


class _Team:
    """What every team MDP has: its agents' rewards ``R`` (N, ...) and the critics' features ``Phi`` (S, q)."""

    R: np.ndarray
    Phi: np.ndarray

    @property
    def n_agents(self) -> int:
        return self.R.shape[0]

    @property
    def n_features(self) -> int:
        return self.Phi.shape[1]


@dataclass(frozen=True, eq=False)
class TeamMDP(_Team):
    """``P`` (S, A, S) over joint actions, ``R`` (N, S, A) each agent's mean local reward, ``actions`` (N,) each
    agent's action count (their product A), ``Phi`` (S, q) the critics' features, ``gamma`` their discount,
    ``start`` (S,) the first state's distribution; ``best`` (S,) where the task knows the team's best joint action in
    every state (its joint index), else None."""

    P: np.ndarray
    R: np.ndarray
    actions: tuple
    Phi: np.ndarray
    gamma: float
    start: np.ndarray
    name: str = "team"
    best: np.ndarray | None = None
    policies: tuple | None = None  # the agents' starting policies (S, A_i), where given (a problem file's)

    @property
    def n_states(self) -> int:
        return self.P.shape[0]

    def joint(self, a: np.ndarray) -> np.ndarray:
        """The joint action's index of the agents' actions ``a`` (..., N)."""
        return np.ravel_multi_index(tuple(np.moveaxis(a, -1, 0)), self.actions)

    def local(self, joint) -> np.ndarray:
        """Each agent's action (..., N) in the joint action ``joint``."""
        return np.stack(np.unravel_index(np.asarray(joint), self.actions), axis=-1)

    def step(self, s: np.ndarray, a: np.ndarray, u: tuple) -> tuple[np.ndarray, np.ndarray]:
        """(s' (B,), each agent's reward (B, N)) of states ``s`` (B,) and actions ``a`` (B, N), s' drawn by the first of
        the uniforms ``u`` (two arrays (B,))."""
        joint = self.joint(a)
        return draw(self.cdf[s, joint], u[0]), self.R[:, s, joint].T

    @property
    def cdf(self) -> np.ndarray:
        return np.cumsum(self.P, axis=-1)

    def chain(self, policies) -> tuple[np.ndarray, np.ndarray]:
        """(P_pi (S, S), R_pi (N, S)): the Markov reward process the policies make of the MDP."""
        pi = joint_policy(policies)
        return np.einsum("sa,sat->st", pi, self.P), np.einsum("sa,nsa->ns", pi, self.R)

    def best_return(self) -> tuple[float | None, np.ndarray | None]:
        """(J*, the best joint action in every state) by `relative_value_iteration` over the joint actions, or (None,
        None) where the table is too large."""
        if self.n_states * self.P.shape[1] > JOINT_LIMIT:
            return None, None

        def sweep(h):
            Q = self.R.mean(axis=0) + self.P @ h
            return Q.max(axis=1), Q.argmax(axis=1)

        return relative_value_iteration(self.n_states, sweep)

    def best_discounted(self) -> tuple[float | None, np.ndarray | None]:
        """(J*_gamma, the best joint action in every state) by `value_iteration`, or (None, None) where the table is
        too large."""
        if self.n_states * self.P.shape[1] > JOINT_LIMIT:
            return None, None

        def sweep(v):
            Q = self.R.mean(axis=0) + self.gamma * self.P @ v
            return Q.max(axis=1), Q.argmax(axis=1)

        v, action = value_iteration(self.n_states, self.gamma, sweep)
        return float((1.0 - self.gamma) * self.start @ v), action


def team_mdp(P, R, Phi, gamma: float, actions, *, start=None, name: str = "team", best=None, policies=None) -> TeamMDP:
    """A `TeamMDP`, checked: shapes, a stochastic P, finite rewards, features of full column rank, starting policies
    (S, A_i) whose rows sum to 1."""
    P, R, Phi = (np.asarray(x, dtype=np.float64) for x in (P, R, Phi))
    actions = tuple(int(a) for a in actions)
    if P.ndim != 3 or P.shape[0] != P.shape[2]:
        raise DgtdInputError(f"P must have shape (S, A, S) over joint actions, got {P.shape}")
    S, A, _ = P.shape
    if not actions or min(actions) < 1 or int(np.prod(actions)) != A:
        raise DgtdInputError(f"the agents' action counts {actions} must multiply to P's {A} joint actions")
    if R.shape != (len(actions), S, A):
        raise DgtdInputError(f"R must have shape (N, S, A) = ({len(actions)}, {S}, {A}), got {R.shape}")
    if not np.isfinite(R).all():
        i, s, a = np.argwhere(~np.isfinite(R))[0]
        raise DgtdInputError(f"R holds NaN or infinite values (first at agent {i}, state {s}, joint action {a})")
    check_stochastic("P(s, a, .)", P.reshape(S * A, S))
    if Phi.ndim != 2 or Phi.shape[0] != S or np.linalg.matrix_rank(Phi) < Phi.shape[1]:
        raise DgtdInputError(f"Phi must be (S, q) = ({S}, q) of full column rank, got shape {Phi.shape}")
    if not 0.0 <= float(gamma) < 1.0:
        raise DgtdInputError(f"gamma must be in [0, 1), got {gamma}")
    start = np.full(S, 1.0 / S) if start is None else np.asarray(start, dtype=np.float64)
    if policies is not None:
        policies = tuple(np.asarray(p, dtype=np.float64) for p in policies)
        for i, (p, n) in enumerate(zip(policies, actions)):
            if p.shape != (S, n):
                raise DgtdInputError(f"policy {i} must have shape (S, A_{i}) = ({S}, {n}), got {p.shape}")
            check_stochastic(f"policy {i}", p)
    best = None if best is None else np.asarray(best)
    return TeamMDP(P, R, actions, Phi, float(gamma), start, name, best, policies)


def joint_policy(policies) -> np.ndarray:
    """pi(a | s) (S, A) of the agents' independent local policies, each (S, A_i): their product, in C order."""
    out = np.ones((policies[0].shape[0], 1))
    for p in policies:
        out = (out[:, :, None] * p[:, None, :]).reshape(out.shape[0], -1)
    return out


def chain_of(mdp, policies) -> tuple[np.ndarray, np.ndarray]:
    """(P_pi (S, S), R_pi (N, S)): the Markov reward process the policies make of the MDP (its own ``chain``)."""
    return mdp.chain(policies)


def draw(cdf: np.ndarray, u: np.ndarray) -> np.ndarray:
    """The index each uniform ``u`` (...) falls at in its cumulative distribution ``cdf`` (..., K)."""
    return np.minimum((cdf <= u[..., None]).sum(axis=-1), cdf.shape[-1] - 1)


def stationary(P_pi: np.ndarray) -> np.ndarray:
    """d with d^T P_pi = d^T, sum d = 1 (solved; the chain's unique one where it is irreducible)."""
    S = P_pi.shape[0]
    lhs = np.vstack([P_pi.T - np.eye(S), np.ones((1, S))])
    d = np.linalg.lstsq(lhs, np.r_[np.zeros(S), 1.0], rcond=None)[0]
    d = np.clip(d, 0.0, None)
    return d / d.sum()


def long_run(P_pi: np.ndarray, start: np.ndarray) -> np.ndarray:
    """The long-run state distribution from ``start``, lim (1/T) sum_t start^T P_pi^t (the Cesaro limit: it exists
    for every finite chain, periodic too). Irreducible: the chain's one stationary d (`stationary`). Else by its
    classes (Puterman 1994, appendix A.4): each closed communicating class C its own stationary d_C, weighted by the
    probability that the chain from ``start`` ends in C (1 on C; on the transient states T the solution h_T of
    (I - P_TT) h_T = P_TC 1); a transient state's share is 0."""
    from dgtd.graphs.topologies import all_reachable

    A = P_pi > 0
    if all_reachable(A) and all_reachable(A.T):
        return stationary(P_pi)
    from scipy.sparse.csgraph import connected_components

    _, label = connected_components(A, directed=True, connection="strong")
    leaves = np.zeros(label.max() + 1, bool)
    tails, heads = np.nonzero(A)
    leaves[label[tails][label[tails] != label[heads]]] = True  # a class with an arc out of it is not closed
    T = np.flatnonzero(leaves[label])  # the transient states: those of a class that is left
    d = np.zeros(P_pi.shape[0])
    for c in np.flatnonzero(~leaves):
        C = np.flatnonzero(label == c)
        h_T = np.linalg.solve(np.eye(T.size) - P_pi[np.ix_(T, T)], P_pi[np.ix_(T, C)].sum(axis=1))
        d[C] = (start[C].sum() + start[T] @ h_T) * stationary(P_pi[np.ix_(C, C)])
    return d


def average_return(mdp, policies) -> float:
    """J(pi) = sum_s d_pi(s) rbar_pi(s): the long-run average team reward of the agents' policies (the module's
    docstring) from the MDP's start (`long_run`: where the policies' chain has more than one closed class the start
    decides which it ends in), by linear algebra on the model."""
    P_pi, R_pi = chain_of(mdp, policies)
    return float(long_run(P_pi, mdp.start) @ R_pi.mean(axis=0))


def discounted_return(mdp, policies) -> float:
    """J_gamma(pi) = (1 - gamma) start^T (I - gamma P_pi)^-1 rbar_pi: the normalised discounted team return from the
    MDP's start (the discounted objective), by linear algebra on the model."""
    P_pi, R_pi = chain_of(mdp, policies)
    v = np.linalg.solve(np.eye(P_pi.shape[0]) - mdp.gamma * P_pi, R_pi.mean(axis=0))
    return float((1.0 - mdp.gamma) * mdp.start @ v)


def objective_return(mdp, policies, objective: str) -> float:
    """The return of the policies under ``objective``: "average" (`average_return`) or "discounted"
    (`discounted_return`)."""
    return average_return(mdp, policies) if objective == "average" else discounted_return(mdp, policies)


def best_of(mdp, objective: str) -> tuple[float | None, np.ndarray | None]:
    """(the best joint policy's return under ``objective``, its joint action in every state where one index): J* by
    relative value iteration (`best_return`), J*_gamma = (1 - gamma) start^T V* by value iteration on the MDP's own
    Bellman maximum (``best_discounted``)."""
    return mdp.best_return() if objective == "average" else mdp.best_discounted()


def value_iteration(S: int, gamma: float, sweep, tol: float = 1e-12, max_sweeps: int = 1_000_000) -> tuple:
    """(V* (S,), the maximising action in every state or None) of a discounted MDP whose Bellman maximum is
    ``sweep(v)`` = (max_a [rbar(s, a) + gamma sum_s' P(s, a, s') v(s')], argmax or None): a contraction by gamma,
    stopped once a sweep changes v by less than ``tol`` (1 - gamma) (V* then within ``tol`` in every state)."""
    v = np.zeros(S)
    for _ in range(max_sweeps):
        new, action = sweep(v)
        if np.abs(new - v).max() < tol * (1.0 - gamma):
            return new, action
        v = new
    raise DgtdInputError("value iteration did not converge")


def critic_target(mdp, policies, objective: str = "discounted", agent: int | None = None) -> np.ndarray:
    """w*(pi) (q,): the fixed point every critic reaches on-policy under the current policies, A w* = b with
    A = Phi^T D (I - gamma P_pi) Phi and b = Phi^T D rbar_pi, D = diag(d_pi) (the paper's section 6, on the chain
    the policies make; d_pi the long-run distribution from the start, `long_run`). Under the average objective the
    differential critic's: gamma = 1 and b = Phi^T D (rbar_pi - J(pi)) (Zhang et al. 2018, Algorithm 2's critic),
    whose A is singular where the features hold the constants (the values are defined up to one): the least-norm
    solution. Where d_pi leaves states out (a transient state) A may be singular too: the least-norm solution, the
    weights the long run says nothing of at 0. ``agent``: the target of a critic of that agent's own reward (an
    independent learner's), not the team's."""
    return critic_targets(mdp, policies, objective, [agent])[0]


def critic_targets(mdp, policies, objective: str, agents) -> np.ndarray:
    """(K, q): `critic_target` of each of ``agents`` (an agent, or None for the team's reward) at once: one chain and
    one matrix A, a right-hand side each (the independent learners' targets of N agents cost one chain, not N)."""
    P_pi, R_pi = chain_of(mdp, policies)
    d = long_run(P_pi, mdp.start)
    Phi = mdp.Phi
    rewards = np.stack([R_pi.mean(axis=0) if agent is None else R_pi[agent] for agent in agents])  # (K, S)
    gamma = mdp.gamma if objective == "discounted" else 1.0
    A = Phi.T @ (d[:, None] * (Phi - gamma * P_pi @ Phi))
    b = Phi.T @ (d[:, None] * (rewards if objective == "discounted" else rewards - (rewards @ d)[:, None]).T)
    if d.min() > 0 and objective == "discounted":
        return np.linalg.solve(A, b).T
    return np.linalg.lstsq(A, b, rcond=None)[0].T


def action_features(n_agents: int, n_states: int, n_actions: int, s, a) -> np.ndarray:
    """f(s, a) = (e_{s, a_1}, ..., e_{s, a_N}), the additive features of a state and joint action, as the indices of
    their ones (..., N) in a vector of N S A: agent j's block j S A + s A + a_j."""
    return np.arange(n_agents) * n_states * n_actions + np.asarray(s)[..., None] * n_actions + np.asarray(a)


def action_critic_target(
    mdp: TeamMDP, policies, objective: str = "discounted", agent: int | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(Phi_Q (S A, F), d_sa (S A,), w*): the expected-SARSA fixed point of the team reward's action values on the
    additive features, A w* = b with A = Phi_Q^T D (Phi_Q - gamma P_sa Pi Phi_Q), b = Phi_Q^T D rbar (the paper's
    section 6 on the chain of state-action pairs, D = diag(d_pi(s) pi(a | s)), P_sa Pi the next pair's law); the
    features are dependent (each agent's block sums to the state's indicator), so w* is the least-norm solution and
    the critics' error is measured in values; under the average objective gamma = 1 and rbar - J(pi) (differential
    values, as `critic_target`'s); ``agent``: of that agent's own reward. None where the joint table is not built (a
    factored MDP)."""
    if not isinstance(mdp, TeamMDP):
        return None
    S, A_joint = mdp.n_states, mdp.P.shape[1]
    A = max(mdp.actions)
    pi = joint_policy(policies)  # (S, A_joint)
    pairs = np.arange(S * A_joint)
    s, joint = pairs // A_joint, pairs % A_joint
    F = mdp.n_agents * S * A
    Phi_Q = np.zeros((S * A_joint, F))
    np.put_along_axis(Phi_Q, action_features(mdp.n_agents, S, A, s, mdp.local(joint)), 1.0, axis=1)
    d = long_run(np.einsum("sa,sat->st", pi, mdp.P), mdp.start)[s] * pi[s, joint]
    next_features = np.einsum("pt,ta,taf->pf", mdp.P[s, joint], pi, Phi_Q.reshape(S, A_joint, F))
    gamma = mdp.gamma if objective == "discounted" else 1.0
    rbar = (mdp.R.mean(axis=0) if agent is None else mdp.R[agent])[s, joint]
    lhs = Phi_Q.T @ (d[:, None] * (Phi_Q - gamma * next_features))
    rhs = Phi_Q.T @ (d * (rbar if objective == "discounted" else rbar - d @ rbar))
    return Phi_Q, d, np.linalg.lstsq(lhs, rhs, rcond=None)[0]


def best_return(mdp) -> tuple[float | None, np.ndarray | None]:
    """(J*, the best joint action in every state, or None where it is not one index) of the MDP (its own
    ``best_return``)."""
    return mdp.best_return()


def relative_value_iteration(S: int, sweep, tol: float = 1e-10, max_sweeps: int = 200_000) -> tuple:
    """(J*, the maximising action in every state or None) of an average-reward MDP whose Bellman maximum is ``sweep(h)``
    = (max_a [rbar(s, a) + sum_s' P(s, a, s') h(s')] (S,), its argmax (S,) or None): relative value iteration on the
    aperiodic chain 1/2 (I + P) (the same optimal policies, the gain halved: doubled back), until the span of a sweep's
    change is below ``tol``; a unichain MDP converges (Puterman 1994, section 8.5.5)."""
    h = np.zeros(S)
    for _ in range(max_sweeps):
        best, action = sweep(h)
        new = 0.5 * (h + best)
        change = new - h
        h = new - new[0]
        if change.max() - change.min() < tol:
            return float(change.max() + change.min()), action
    raise DgtdInputError("relative value iteration did not converge: is the team MDP multichain?")


def entropy(policies, d: np.ndarray) -> np.ndarray:
    """Each agent's policy entropy (N,), in nats, averaged over the states by ``d``."""
    return np.array([float(d @ -(p * np.log(np.where(p > 0, p, 1.0))).sum(axis=1)) for p in policies])


def pull_away(n_agents: int = 4, n_states: int = 3, bonus: float = 1.0, gamma: float = 0.5, seed: int = 0) -> TeamMDP:
    """A team MDP whose local rewards pull every agent away from the team's best joint action.

    Binary actions; in state s the team's action is t(s) = s mod 2. Agent i earns ``bonus`` when it deviates
    (a_i != t(s)) and loses h = 2 bonus / (N - 1) for each other agent that deviates, plus c0 = 2 bonus so that every
    reward is >= 0:

        R_i(s, a) = c0 + bonus [a_i != t(s)] - h sum_{j != i} [a_j != t(s)].

    Whatever the others do, deviating pays agent i ``bonus`` more, so learners of their own reward deviate; but the
    team's reward is rbar(s, a) = c0 - (bonus / N) #deviators, largest (c0) when nobody deviates, in every state, and
    so J* = c0 whatever the transitions, which are random per joint action (rows uniform on the simplex, seeded).

    The critics' discount is 1/2: an agent's share of the team's gain, bonus / N, is small beside the values
    (c0 / (1 - gamma)), and a critic's error of a few per cent of them swamps it; at gamma = 0.9 a centralised
    learner's seed stood at 0.64 on the best action after 20 000 steps (at 1/2, 0.996; measured)."""
    if n_agents < 2 or n_states < 1:
        raise DgtdInputError("pull-away needs at least 2 agents and 1 state")
    rng = np.random.default_rng(seed)
    most = int(np.log2(JOINT_LIMIT / max(n_states, 1)))  # agents whose joint table fits
    if n_agents > most:
        raise DgtdInputError(
            f"pull-away builds its joint table, {n_states} states x 2^{n_agents} joint actions: too large; take at "
            f"most {most} agents (the factored task takes thousands)"
        )
    actions = (2,) * n_agents
    A = 2**n_agents
    P = rng.dirichlet(np.ones(n_states), size=(n_states, A))
    team = np.arange(n_states) % 2
    a = np.stack(np.unravel_index(np.arange(A), actions), axis=-1)  # (A, N)
    deviates = (a[None, :, :] != team[:, None, None]).astype(np.float64)  # (S, A, N)
    h = 2.0 * bonus / (n_agents - 1)
    others = deviates.sum(axis=2, keepdims=True) - deviates
    R = np.moveaxis(2.0 * bonus + bonus * deviates - h * others, 2, 0)  # (N, S, A)
    best = np.ravel_multi_index(tuple(np.tile(team[:, None], (1, n_agents)).T), actions)
    return team_mdp(P, R, np.eye(n_states), gamma, actions, name=f"pull-away-{n_agents}", best=best)


@dataclass(frozen=True, eq=False)
class FactoredMDP(_Team):
    """A team MDP whose joint table is never built: the agents form G groups of m (``groups`` (G, m), a partition);
    at every step one group, drawn uniformly, moves the state by its own table, so that

        P(s, a, s') = (1/G) sum_g P_g(s, a_g, s'),     ``Pg`` (G, S, K, S), a_g group g's joint action (K = A^m),

    and agent i's reward R_i(s, a_i) depends on its own action (``R`` (N, S, A)). Each agent's action enters the
    transition through its group's few (Zhang et al.'s 20-agent experiment, where P is a table over all 2^20 joint
    actions, in a form whose memory is G S K S: 1 000 agents is a run, not a table). The exact quantities need no
    joint table: P_pi sums the groups' chains, and J*'s Bellman maximum separates over the groups (the reward is a sum
    of the agents' terms, the transition a mixture of the groups')."""

    Pg: np.ndarray
    groups: np.ndarray
    R: np.ndarray
    actions: tuple
    Phi: np.ndarray
    gamma: float
    start: np.ndarray
    name: str = "factored"
    best: None = None
    policies: tuple | None = None  # the agents' starting policies (S, A_i), where given (`dgtd learn --from`)

    @property
    def n_states(self) -> int:
        return self.Pg.shape[1]

    def _group_actions(self) -> tuple:
        return (self.actions[0],) * self.groups.shape[1]

    def step(self, s: np.ndarray, a: np.ndarray, u: tuple) -> tuple[np.ndarray, np.ndarray]:
        """(s', rewards (B, N)): the group drawn by the second uniform, s' from its table by the first."""
        G = len(self.groups)
        g = np.minimum((u[1] * G).astype(np.int64), G - 1)
        mine = np.take_along_axis(a, self.groups[g], axis=1)  # (B, m): the drawn group's actions
        k = np.ravel_multi_index(tuple(mine.T), self._group_actions())
        cdf = np.cumsum(self.Pg[g, s, k], axis=-1)
        return draw(cdf, u[0]), np.take_along_axis(self.R[:, s, :].transpose(1, 0, 2), a[:, :, None], axis=2)[:, :, 0]

    def chain(self, policies) -> tuple[np.ndarray, np.ndarray]:
        """(P_pi, R_pi): the groups' chains averaged, each under its agents' joint policy; each agent's mean reward."""
        pi = np.stack(policies)  # (N, S, A): every agent's, stacked (equal action counts)
        joint = pi[self.groups[:, 0]]  # (G, S, A): each group's joint policy, built agent by agent in C order
        for j in range(1, self.groups.shape[1]):
            joint = (joint[..., :, None] * pi[self.groups[:, j]][..., None, :]).reshape(
                joint.shape[0], self.n_states, -1
            )
        P_pi = np.einsum("gsk,gskt->st", joint, self.Pg) / len(self.groups)
        return P_pi, (pi * self.R).sum(axis=2)

    def _group_rewards(self) -> np.ndarray:
        """(G, S, K): each group's part of rbar at each of its joint actions."""
        ks = np.stack(np.unravel_index(np.arange(self.Pg.shape[2]), self._group_actions()), axis=-1)  # (K, m)
        return (
            np.stack([sum(self.R[i][:, ks[:, j]] for j, i in enumerate(members)) for members in self.groups])
            / self.n_agents
        )

    def best_return(self) -> tuple[float, None]:
        """(J*, None): relative value iteration whose maximum over the 2^N joint actions is a sum of the groups'
        maxima over their K."""
        G, S = len(self.groups), self.n_states
        reward = self._group_rewards()

        def sweep(h):
            return (reward + self.Pg @ h / G).max(axis=2).sum(axis=0), None

        return relative_value_iteration(S, sweep)[0], None

    def best_discounted(self) -> tuple[float, None]:
        """(J*_gamma, None): value iteration whose maximum separates over the groups as `best_return`'s does."""
        G = len(self.groups)
        reward = self._group_rewards()

        def sweep(v):
            return (reward + self.gamma * self.Pg @ v / G).max(axis=2).sum(axis=0), None

        v = value_iteration(self.n_states, self.gamma, sweep)[0]
        return float((1.0 - self.gamma) * self.start @ v), None


def factored(
    n_agents: int = 1000, n_states: int = 10, group: int = 2, gamma: float = 0.5, seed: int = 0, name: str = "factored"
) -> FactoredMDP:
    """A random factored team MDP: binary actions, groups of ``group`` consecutive agents, each group's table's rows
    uniform on the simplex, rewards R_i(s, a_i) uniform in [0, 4] (as Zhang et al.'s), one-hot features, seeded."""
    if n_agents < 2 or n_agents % group:
        raise DgtdInputError(
            f"a factored task needs at least 2 agents, a multiple of its groups' {group}; got {n_agents}"
        )
    rng = np.random.default_rng(seed)
    G, K = n_agents // group, 2**group
    Pg = rng.dirichlet(np.ones(n_states), size=(G, n_states, K))
    R = rng.uniform(0.0, 4.0, (n_agents, n_states, 2))
    groups = np.arange(n_agents).reshape(G, group)
    start = np.full(n_states, 1.0 / n_states)
    return FactoredMDP(Pg, groups, R, (2,) * n_agents, np.eye(n_states), float(gamma), start, name)


def zhang_20(n_agents: int = 20, n_states: int = 20, seed: int = 0) -> FactoredMDP:
    """Zhang et al.'s 20-agent setting (ICML 2018, section 5.1: 20 states, binary actions, rewards uniform in [0, 4]),
    its transitions factored over groups of 2 (`FactoredMDP`): their joint table would hold 20 x 2^20 x 20 numbers."""
    return factored(n_agents, n_states, 2, seed=seed, name=f"zhang-{n_agents}")


def delayed_reward(
    n_agents: int = 2, n_states: int = 4, prize: float = 3.0, small: float = 0.3, gamma: float = 0.5
) -> TeamMDP:
    """A team MDP whose best reward comes late: binary actions (1: advance); when every agent advances the state moves
    on, s -> s + 1, paying nothing, and from the last state back to 0 paying ``prize``; any other joint action keeps
    the state and pays ``small``. Every agent is paid the team's reward. The long-run average is best advancing
    always, J* = prize / S (0.75), against ``small`` (0.3) for staying; at the task's gamma 1/2 the discounted
    objective prefers to stay in state 0 (the prize 3 gamma^3 = 0.375 lies beyond 0.3 / (1 - gamma) = 0.6), a
    policy whose long-run average is 0.3. Actors that move before their critics have met the prize
    commit to the small reward too (`dgtd.algorithms.actor`)."""
    if n_agents < 1 or n_states < 2:
        raise DgtdInputError("delayed-reward needs at least 1 agent and 2 states")
    most = int(np.log2(JOINT_LIMIT / n_states))
    if n_agents > most:
        raise DgtdInputError(f"delayed-reward builds its joint table: take at most {most} agents")
    A = 2**n_agents
    P, R = np.zeros((n_states, A, n_states)), np.full((n_agents, n_states, A), float(small))
    P[np.arange(n_states), :, np.arange(n_states)] = 1.0  # (any joint action but all-advance: stay)
    P[:, A - 1, :] = np.roll(np.eye(n_states), 1, axis=1)
    R[:, :, A - 1] = 0.0
    R[:, n_states - 1, A - 1] = prize
    best = np.full(n_states, A - 1)
    return team_mdp(P, R, np.eye(n_states), gamma, (2,) * n_agents, name=f"delayed-reward-{n_agents}", best=best)


def chen_6(n_agents: int = 6, n_states: int = 5) -> TeamMDP:
    """Chen, Zhou, Chen and Zou's (ICML 2022) simulated setting, re-created from their code's seeds (zuopaoyoutao/MACE
    at e568715, `init(seed_init=0)` and `omega0` after `set_seed(5)`): 6 agents, 5 states, binary actions, the start
    xi = |z| / sum |z| and every row P(s, a, .) = |z| / sum |z| for standard normal z, rewards r_m(s, a, s') uniform in
    [0, 1] (here their mean over s'), gamma 0.95, tabular features, and their starting policies softmax(omega0) with
    omega0 standard normal; drawn in their order from numpy's legacy generator. Their J of those policies, the
    normalised discounted return from xi, is 0.49226650802874 (`discounted_return`: theirs to 1e-15)."""
    if (n_agents, n_states) != (6, 5):
        raise DgtdInputError(
            f"chen-6 is their 6 agents and 5 states, re-created from their seeds; got {n_agents} and {n_states}"
        )
    rng = np.random.RandomState(0)  # (their np.random.seed(0): the legacy generator, numbers in their order)
    xi = np.abs(rng.normal(size=n_states))
    P = np.abs(rng.normal(size=(n_states,) + (2,) * n_agents + (n_states,)))
    P = (P / P.sum(axis=-1, keepdims=True)).reshape(n_states, 2**n_agents, n_states)
    R = rng.uniform(size=(n_states,) + (2,) * n_agents + (n_states, n_agents))
    R = np.einsum("sat,nsat->nsa", P, np.moveaxis(R, -1, 0).reshape(n_agents, n_states, 2**n_agents, n_states))
    omega = np.random.RandomState(5).normal(size=(n_agents, n_states, 2))
    policies = [np.exp(w) / np.exp(w).sum(axis=1, keepdims=True) for w in omega]
    return team_mdp(
        P, R, np.eye(n_states), 0.95, (2,) * n_agents, start=xi / xi.sum(), name="chen-6", policies=policies
    )


TASKS: dict[str, Callable[..., TeamMDP | FactoredMDP]] = {
    "pull-away": pull_away,
    "delayed-reward": delayed_reward,
    "zhang-20": zhang_20,
    "factored": factored,
    "chen-6": chen_6,
}
"""The learning tasks by name, each a function of n_agents and n_states (`dgtd learn TASK --agents --states`)."""
