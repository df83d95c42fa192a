"""Markov chains estimated from a simulator's transitions, and tabular TD(0) on the same samples.

A simulator with hidden state (a robot's waypoint, its exact position) seen through a finite grid has no
closed-form transition matrix. For tabular features the TD fixed point depends on the data only through
the stationary frequencies of pairs (s, s'): E[e_s (r(s) + gamma w(s') - w(s))] = D (r + gamma P w - w) with
P(s, s') = Pr(s_{k+1} = s' | s_k = s) under the stationary law. So the exact w* of the chain
P_hat = counts / row sums is the point every tabular TD method converges to on the simulator's samples,
up to the estimation error of those frequencies; `dgtd.problems.exact` then treats P_hat as the model.
"""

from __future__ import annotations

import numpy as np

from dgtd.errors import DgtdInputError


def chain_from_counts(counts: np.ndarray) -> np.ndarray:
    """P_hat(s, s') = n(s, s') / sum_t n(s, t), the maximum-likelihood transition matrix of the counts (S, S)."""
    counts = np.asarray(counts, dtype=np.float64)
    rows = counts.sum(axis=1)
    missing = np.flatnonzero(rows == 0)
    if missing.size:
        raise DgtdInputError(
            f"{missing.size} grid states (first: {missing[0]}) were never visited in the reference run; "
            "lengthen it (more steps or more robots) so that every state is seen"
        )
    return counts / rows[:, None]


def visit_frequencies(counts: np.ndarray) -> np.ndarray:
    """How often each state was the origin of a counted transition, (S,), summing to one."""
    rows = np.asarray(counts, dtype=np.float64).sum(axis=1)
    return rows / rows.sum()


def tabular_w_star(P: np.ndarray, r_mean: np.ndarray, gamma: float) -> np.ndarray:
    """w* = (I - gamma P)^-1 r_mean: with Phi = I and d > 0 the projected Bellman equation is the Bellman equation."""
    return np.linalg.solve(np.eye(P.shape[0]) - gamma * P, r_mean)


def minibatch_td(
    w: np.ndarray,
    n_seen: np.ndarray,
    s: np.ndarray,
    s_next: np.ndarray,
    r_mean: np.ndarray,
    gamma: float,
    omega: float = 0.7,
) -> tuple[np.ndarray, np.ndarray]:
    """One step of centralised tabular TD(0) on a minibatch of simultaneous transitions (s_j, s'_j).

    Each visited state moves by its mean TD error delta_j = r(s_j) + gamma w(s'_j) - w(s_j) times
    c_s / n_s^omega, where c_s is its number of samples in this minibatch and n_s its count so far: the sum of
    the per-sample steps 1 / n^omega (omega in (1/2, 1], the Robbins-Monro conditions) over the minibatch.
    Returns the new (w, n_seen); the inputs are not modified.
    """
    S = w.shape[0]
    delta = r_mean[s] + gamma * w[s_next] - w[s]
    c = np.bincount(s, minlength=S)
    total = np.bincount(s, weights=delta, minlength=S)
    n_new = n_seen + c
    seen = c > 0
    step = np.zeros(S)
    step[seen] = np.minimum(1.0, c[seen] / n_new[seen] ** omega) * total[seen] / c[seen]
    return w + step, n_new
