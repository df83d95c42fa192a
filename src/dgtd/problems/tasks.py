"""The standard policy-evaluation tasks of the field, as multi-agent problems with exact solutions.

Each builder returns a validated `Problem` whose N agents' rewards average exactly to the task's reward
but differ across agents (`split_rewards`), so that no agent can learn w* alone.

- `baird`: Baird's counterexample as in Sutton and Barto (2018), section 11.2, off-policy.
- `boyan`: the episodic Boyan chain of Boyan (2002) and Dann, Neumann and Peters (2014): the last state is
  terminal (the return ends there) and the next episode starts at the first state.
- `random_mdp`: the 400-state, 10-action random MDP with 200 random features of Dann et al. (2014).
- `garnet`: random ergodic chains with a given number of states and successors per state.
"""

from __future__ import annotations

import numpy as np

from dgtd.errors import DgtdInputError
from dgtd.problems.model import Problem, chain_period, check_irreducible, make_problem


def split_rewards(
    mean: np.ndarray,
    n_agents: int,
    rng: np.random.Generator,
    spread: float = 1.0,
    low: float | None = None,
    high: float | None = None,
) -> np.ndarray:
    """Agents' rewards r_i = mean + spread * h * z_i with sum_i z_i = 0 exactly and |z_i| <= 1, shape (N, *mean.shape).

    The z_i are uniform draws centred over agents. With bounds [low, high] the half-width h is
    min(mean - low, high - mean) per entry, so every r_i stays in [low, high] (rewards in [0, 1] stay
    there); without bounds h = max(1, |mean|_inf), a perturbation on the scale of the reward.
    """
    mean = np.asarray(mean, dtype=np.float64)
    z = rng.uniform(-1.0, 1.0, (n_agents,) + mean.shape)
    z -= z.mean(axis=0)
    z /= max(float(np.abs(z).max()), 1e-300)
    # the room each mean reward leaves: a scale of its own, or up to the bounds [low, high]
    h = max(1.0, float(np.abs(mean).max())) if low is None else np.minimum(mean - low, high - mean)
    r = mean + spread * h * z
    r -= r.mean(axis=0) - mean  # the agents' average is the task's reward to rounding
    return r if low is None else np.clip(r, low, high)


BAIRD_W0 = (1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 10.0, 1.0)


def baird(n_agents: int = 5, seed: int = 0) -> Problem:
    """Baird's counterexample (Sutton and Barto 2018, Fig. 11.1): 7 states, 8 features, gamma 0.99.

    States 0..5 are the upper states, 6 the lower one; phi(upper i) = 2 e_i + e_7, phi(lower) = e_6 + 2 e_7,
    so the 8 features are linearly dependent on 7 states. Behaviour policy: 'dashed' (action 0) with
    probability 6/7, to one of the six upper states uniformly; 'solid' (action 1) with 1/7, to the lower
    state. Target policy: always 'solid', so the ratios are 0 (dashed) and 7 (solid). The target chain P
    sends every state to the lower one (it is reducible); the behaviour chain, whose stationary
    distribution d is uniform and which sets every exact quantity, is ergodic. Initial weights
    w0 = (1, 1, 1, 1, 1, 1, 10, 1).

    The task's reward is zero. Agent i's mean reward at (s, a) is a zero-mean perturbation z_i(s, a) in
    [-1, 1] with sum_i z_i = 0: the agents' rewards average to zero but each agent's is not zero, so they
    must be signed (the paper's rewards in [0, sigma] cannot average to zero unless all are zero; a
    constant shift would change the task). The exact w* is then w0's component along the null space of
    Phi: (22/13) (1, 1, 1, 1, 1, 1, 4, -2), with values Phi w* = 0 (`dgtd.problems.exact.w_star`).
    """
    S, upper, lower = 7, 6, 6
    P_sample = np.zeros((S, 2, S))
    P_sample[:, 0, :upper] = (6.0 / 7.0) / upper
    P_sample[:, 1, lower] = 1.0 / 7.0
    ratio = np.tile([0.0, 7.0], (S, 1))
    P = np.zeros((S, S))
    P[:, lower] = 1.0
    Phi = np.zeros((S, 8))
    Phi[np.arange(upper), np.arange(upper)] = 2.0
    Phi[:upper, 7] = 1.0
    Phi[lower, 6], Phi[lower, 7] = 1.0, 2.0
    R_sample = split_rewards(np.zeros((S, 2)), n_agents, np.random.default_rng(seed))
    return make_problem(
        P,
        R_sample[:, :, 1],
        Phi,
        0.99,
        P_sample=P_sample,
        ratio=ratio,
        R_sample=R_sample,
        name="baird",
        w0=BAIRD_W0,
        signed_rewards=True,
        dependent_features=True,
        state_labels=tuple(f"upper {i + 1}" for i in range(upper)) + ("lower",),
    )


def triangular_features(n_states: int, n_features: int) -> np.ndarray:
    """Dann et al.'s Boyan-chain features: phi_j(s) = max(0, 1 - |s + 1 - c_j| / a), centres c_j evenly
    spaced on [1, n_states], a = (n_states - 1) / (n_features - 1); shape (S, q)."""
    c = np.linspace(1.0, n_states, n_features)
    a = (n_states - 1.0) / (n_features - 1.0)
    s = np.arange(n_states, dtype=np.float64)[:, None]
    return np.maximum(0.0, 1.0 - np.abs(s + 1.0 - c) / a)


def boyan_chain(n_states: int = 14) -> tuple[np.ndarray, np.ndarray]:
    """(P, r) of the Boyan chain: from s <= S - 3 to s + 1 or s + 2 with probability 1/2 and reward -3; from S - 2
    to the terminal state S - 1 with reward -2; from S - 1 the next episode starts at state 0 (reward 0), a
    transition that carries no discount (`dgtd.problems.model.Problem.terminal`)."""
    S = n_states
    P = np.zeros((S, S))
    r = np.full(S, -3.0)
    for s in range(S - 2):
        P[s, s + 1] = P[s, s + 2] = 0.5
    P[S - 2, S - 1] = 1.0
    r[S - 2] = -2.0
    P[S - 1, 0] = 1.0  # restart, so that the chain is ergodic
    r[S - 1] = 0.0
    return P, r


def boyan(n_agents: int = 10, seed: int = 0, n_states: int = 14, gamma: float = 0.95) -> Problem:
    """The Boyan chain of Dann et al. (2014): 14 states, 4 triangular features, gamma 0.95, on-policy, episodic.

    The last state is terminal: its value is 0, the return of every episode ends there, and the next episode
    starts at state 0; d is the stationary distribution of the chain of episodes. The true values are the
    published ones (-21.479 at state 0 ... -3.950, -2, 0 with 14 states and gamma 0.95; with 13 states and gamma 1
    they are linear, and w* = (-24, -16, -8, 0)). Agent i's reward is the chain's (-3, or -2 before the terminal
    state) plus a zero-mean perturbation of up to +-3 (`split_rewards`); the rewards are signed, as the chain's are.
    """
    P, r = boyan_chain(n_states)
    R = split_rewards(r, n_agents, np.random.default_rng(seed))
    terminal = np.arange(n_states) == n_states - 1
    return make_problem(
        P, R, triangular_features(n_states, 4), gamma, name="boyan", signed_rewards=True, terminal=terminal
    )


def random_walk(n_agents: int = 10, seed: int = 0, n_states: int = 20, gamma: float = 0.9) -> Problem:
    """An on-policy random walk on a chain of ``n_states`` states with tabular (one-hot) features: from each state one
    step left or right with probability 1/2 (staying put at either end), gamma 0.9. The mean reward rises from 0 at
    the left end to 1 at the right; agent i's is it perturbed within [0, 1] (`split_rewards`). Where TD(0) is at its
    best (on-policy, tabular) and the gradient-TD family was slowest: the task on which a method's on-policy pace
    is measured."""
    S = n_states
    P = np.zeros((S, S))
    for s in range(S):
        P[s, max(s - 1, 0)] += 0.5
        P[s, min(s + 1, S - 1)] += 0.5
    R = split_rewards(np.linspace(0.0, 1.0, S), n_agents, np.random.default_rng(seed), low=0.0, high=1.0)
    return make_problem(P, R, np.eye(S), gamma, name="random-walk")


def _normalise(x: np.ndarray) -> np.ndarray:
    return x / x.sum(axis=-1, keepdims=True)


def random_mdp(
    n_agents: int = 10,
    off_policy: bool = False,
    seed: int = 0,
    n_states: int = 400,
    n_actions: int = 10,
    n_features: int = 200,
    gamma: float = 0.95,
) -> Problem:
    """The random MDP of Dann, Neumann and Peters (2014): 400 states, 10 actions, 200 features, gamma 0.95.

    P(s' | s, a) proportional to U[0, 1] + 1e-5; rewards r(s, a, s') ~ U[0, 1]; features: 199 entries
    U[0, 1] and a constant 1; policies pi(a|s) proportional to U[0, 1]. On-policy the agents follow pi;
    off-policy they follow a second random policy beta and evaluate pi with ratios pi / beta. Agent i's
    mean reward at (s, a) is the task's plus a zero-mean perturbation that keeps it in [0, 1].
    All draws come from ``np.random.default_rng(seed)``.
    """
    rng = np.random.default_rng(seed)
    S, A, q = n_states, n_actions, n_features
    P_sas = _normalise(rng.uniform(size=(S, A, S)) + 1e-5)
    r_sa = np.einsum("sat,sat->sa", P_sas, rng.uniform(size=(S, A, S)))
    Phi = np.ones((S, q))
    Phi[:, :-1] = rng.uniform(size=(S, q - 1))
    pi = _normalise(rng.uniform(size=(S, A)))
    beta = _normalise(rng.uniform(size=(S, A))) if off_policy else pi
    R_sample = split_rewards(r_sa, n_agents, rng, low=0.0, high=1.0)
    return make_problem(
        np.einsum("sa,sat->st", pi, P_sas),
        np.einsum("sa,nsa->ns", pi, R_sample),
        Phi,
        gamma,
        P_sample=beta[:, :, None] * P_sas,
        ratio=pi / beta,
        R_sample=R_sample,
        sigma=1.0,
        name="random-mdp-off" if off_policy else "random-mdp",
    )


def garnet(
    n_states: int = 30,
    branching: int = 3,
    n_agents: int = 10,
    n_features: int = 8,
    gamma: float = 0.9,
    seed: int = 0,
    max_tries: int = 1000,
) -> Problem:
    """A Garnet chain (Archibald, McKinnon and Thomas 1995): each state moves to ``branching`` distinct random
    successors with probabilities from a uniform random partition of [0, 1] (Dirichlet(1, ..., 1)).

    Draws are repeated (same generator) until the chain is irreducible and aperiodic, so that d is unique
    and Markovian samples settle. Features: n_features - 1 entries U[0, 1] and a constant 1 (redrawn until
    of full rank). Mean rewards r(s) ~ U[0, 1], split over agents within [0, 1].
    """
    if not 1 <= branching <= n_states:
        raise DgtdInputError(f"branching must lie in 1..{n_states} (successors per state), got {branching}")
    if not 1 <= n_features <= n_states:
        raise DgtdInputError(f"n_features must lie in 1..{n_states} (at most one feature per state), got {n_features}")
    rng = np.random.default_rng(seed)
    S = n_states
    for _ in range(max_tries):
        P = np.zeros((S, S))
        for s in range(S):
            nxt = rng.choice(S, size=branching, replace=False)
            P[s, nxt] = rng.dirichlet(np.ones(branching))
        try:
            check_irreducible("P", P)
        except DgtdInputError:
            continue
        if chain_period(P) == 1:
            break
    else:
        raise DgtdInputError(
            f"no ergodic Garnet chain with {S} states and {branching} successors in {max_tries} draws; raise branching"
        )
    Phi = np.ones((S, n_features))
    for _ in range(max_tries):
        Phi[:, :-1] = rng.uniform(size=(S, n_features - 1))
        if np.linalg.matrix_rank(Phi) == n_features:
            break
    R = split_rewards(rng.uniform(size=S), n_agents, rng, low=0.0, high=1.0)
    return make_problem(P, R, Phi, gamma, sigma=1.0, name="garnet")
