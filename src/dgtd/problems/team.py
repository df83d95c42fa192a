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
value iteration over the joint actions (`best_return`: exact to 1e-10 where S x A fits). The critics evaluate the
discounted value of the team reward, V_pi = Phi w; their fixed point under the current policy, w*(pi), is the
exact one of the paper's section 6 on the Markov reward process (P_pi, R_pi) (`critic_target`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dgtd.errors import DgtdInputError
from dgtd.problems.model import check_stochastic

JOINT_LIMIT = 1 << 20  # states x joint actions beyond which no joint table is built


@dataclass(frozen=True, eq=False)
class TeamMDP:
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

    @property
    def n_states(self) -> int:
        return self.P.shape[0]

    @property
    def n_agents(self) -> int:
        return self.R.shape[0]

    @property
    def n_features(self) -> int:
        return self.Phi.shape[1]

    def joint(self, a: np.ndarray) -> np.ndarray:
        """The joint action's index of the agents' actions ``a`` (..., N)."""
        return np.ravel_multi_index(tuple(np.moveaxis(a, -1, 0)), self.actions)

    def local(self, joint) -> np.ndarray:
        """Each agent's action (..., N) in the joint action ``joint``."""
        return np.stack(np.unravel_index(np.asarray(joint), self.actions), axis=-1)


def team_mdp(P, R, Phi, gamma: float, actions, *, start=None, name: str = "team", best=None) -> TeamMDP:
    """A `TeamMDP`, checked: shapes, a stochastic P, finite rewards, features of full column rank."""
    P, R, Phi = (np.asarray(x, dtype=np.float64) for x in (P, R, Phi))
    actions = tuple(int(a) for a in actions)
    if P.ndim != 3 or P.shape[0] != P.shape[2]:
        raise DgtdInputError(f"P must have shape (S, A, S) over joint actions, got {P.shape}")
    S, A, _ = P.shape
    if not actions or min(actions) < 1 or int(np.prod(actions)) != A:
        raise DgtdInputError(f"the agents' action counts {actions} must multiply to P's {A} joint actions")
    if R.shape != (len(actions), S, A) or not np.isfinite(R).all():
        raise DgtdInputError(f"R must be finite with shape (N, S, A) = ({len(actions)}, {S}, {A}), got {R.shape}")
    check_stochastic("P(s, a, .)", P.reshape(S * A, S))
    if Phi.ndim != 2 or Phi.shape[0] != S or np.linalg.matrix_rank(Phi) < Phi.shape[1]:
        raise DgtdInputError(f"Phi must be (S, q) = ({S}, q) of full column rank, got shape {Phi.shape}")
    if not 0.0 <= float(gamma) < 1.0:
        raise DgtdInputError(f"gamma must be in [0, 1), got {gamma}")
    start = np.full(S, 1.0 / S) if start is None else np.asarray(start, dtype=np.float64)
    return TeamMDP(P, R, actions, Phi, float(gamma), start, name, None if best is None else np.asarray(best))


def joint_policy(policies) -> np.ndarray:
    """pi(a | s) (S, A) of the agents' independent local policies, each (S, A_i): their product, in C order."""
    out = np.ones((policies[0].shape[0], 1))
    for p in policies:
        out = (out[:, :, None] * p[:, None, :]).reshape(out.shape[0], -1)
    return out


def chain_of(mdp: TeamMDP, policies) -> tuple[np.ndarray, np.ndarray]:
    """(P_pi (S, S), R_pi (N, S)): the Markov reward process the policies make of the MDP."""
    pi = joint_policy(policies)
    return np.einsum("sa,sat->st", pi, mdp.P), np.einsum("sa,nsa->ns", pi, mdp.R)


def stationary(P_pi: np.ndarray) -> np.ndarray:
    """d with d^T P_pi = d^T, sum d = 1 (solved; the chain's unique one where it is irreducible)."""
    S = P_pi.shape[0]
    lhs = np.vstack([P_pi.T - np.eye(S), np.ones((1, S))])
    d = np.linalg.lstsq(lhs, np.r_[np.zeros(S), 1.0], rcond=None)[0]
    d = np.clip(d, 0.0, None)
    return d / d.sum()


def average_return(mdp: TeamMDP, policies) -> float:
    """J(pi) = sum_s d_pi(s) rbar_pi(s): the long-run average team reward of the agents' policies (the module's
    docstring), by linear algebra on the model."""
    P_pi, R_pi = chain_of(mdp, policies)
    return float(stationary(P_pi) @ R_pi.mean(axis=0))


def critic_target(mdp: TeamMDP, policies) -> np.ndarray:
    """w*(pi) (q,): the fixed point every critic reaches on-policy under the current policies, A w* = b with
    A = Phi^T D (I - gamma P_pi) Phi and b = Phi^T D rbar_pi, D = diag(d_pi) (the paper's section 6, on the chain
    the policies make)."""
    P_pi, R_pi = chain_of(mdp, policies)
    d = stationary(P_pi)
    Phi = mdp.Phi
    A = Phi.T @ (d[:, None] * (Phi - mdp.gamma * P_pi @ Phi))
    b = Phi.T @ (d * R_pi.mean(axis=0))
    return np.linalg.solve(A, b)


def best_return(mdp: TeamMDP, tol: float = 1e-10, max_sweeps: int = 200_000) -> tuple[float, np.ndarray]:
    """(J*, the best joint action in every state (S,)): relative value iteration over the joint actions on the
    aperiodic chain 1/2 (I + P) (the same optimal policies, the gain halved: doubled back), until the span of a
    sweep's change is below ``tol``; a unichain MDP converges (Puterman 1994, section 8.5.5)."""
    S, A, _ = mdp.P.shape
    rbar = mdp.R.mean(axis=0)
    h = np.zeros(S)
    for _ in range(max_sweeps):
        Q = 0.5 * rbar + 0.5 * (h[:, None] + mdp.P @ h)
        new = Q.max(axis=1)
        change = new - h
        h = new - new[0]
        if change.max() - change.min() < tol:
            break
    else:
        raise DgtdInputError("relative value iteration did not converge: is the team MDP multichain?")
    gain = 2.0 * 0.5 * (change.max() + change.min())
    return float(gain), Q.argmax(axis=1)


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
    actions = (2,) * n_agents
    A = 2**n_agents
    if n_states * A > JOINT_LIMIT:
        raise DgtdInputError(f"pull-away's joint table of {n_states} x {A} is too large; take fewer agents")
    P = rng.dirichlet(np.ones(n_states), size=(n_states, A))
    team = np.arange(n_states) % 2
    a = np.stack(np.unravel_index(np.arange(A), actions), axis=-1)  # (A, N)
    deviates = (a[None, :, :] != team[:, None, None]).astype(np.float64)  # (S, A, N)
    h = 2.0 * bonus / (n_agents - 1)
    others = deviates.sum(axis=2, keepdims=True) - deviates
    R = np.moveaxis(2.0 * bonus + bonus * deviates - h * others, 2, 0)  # (N, S, A)
    best = np.ravel_multi_index(tuple(np.tile(team[:, None], (1, n_agents)).T), actions)
    return team_mdp(P, R, np.eye(n_states), gamma, actions, name=f"pull-away-{n_agents}", best=best)


TASKS = {"pull-away": pull_away}
