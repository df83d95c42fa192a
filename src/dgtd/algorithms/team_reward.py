"""Each networked agent's estimate of the team's reward (Zhang, Yang, Liu, Zhang and Basar 2018, Algorithm 2): a
linear regression rhat_i = lambda_i^T f(s, a) of its own reward r_i, mixed with its neighbours' estimates, so that
the consensus of the regressions is the regression of the team's mean reward rbar. f(s, a) is additive over the
agents, (g(s) e_{a_1}^T, ..., g(s) e_{a_N}^T): g(s) = e_s on a model (a table: it represents any team reward that is
a sum of per-agent terms exactly), the critics' features phi(s) in a simulator.

One step, as `dgtd.run.learn.round_end` moves it:

    lambda_i <- lambda_i - sum_j W_ij (lambda_i - lambda_j) + nu_k (r_i - rhat_i) f(s, a),

W the Metropolis mixing over the links up, nu_k = `regression_rate` (a normalised least-mean-squares step: 1/|f|^2
times `mean_step`). The same running-mean step moves the average objective's mu_i and mu~_i (`mean_update`). Scalars
or arrays: the NumPy, simulator and compiled learners run these definitions.

That estimate is N A m numbers an agent and O(N^2 A m) a step in all. The neighbourhood's (``--team-reward
neighbourhood``) is O(degree) an agent: agent i keeps, for itself and each neighbour k of the graph (its slots), a
regression lambda_ik of r_k on g(s) e_{a_i}^T, i.e. of E[r_k | s, a_i] under the others' current policies, moved
only when k's reward of that step was heard (one number over each link a step: unbiased under any loss that does not
depend on the state or the actions), and takes

    rhat_i = (1/N) sum_{k in N_i and i} lambda_ik^T g(s) e_{a_i}

as the team's reward in its advantage. By the policy-gradient theorem agent i's gradient is E[(rbar - J + V(s') -
V(s)) psi_i(s, a_i)], and any term of rbar whose mean given (s, a_i) does not depend on a_i drops out of it (psi_i has
mean 0 over a_i): so rhat_i gives the team's gradient exactly where an agent's action moves only its neighbours'
rewards (E[r_k | s, a_i] the same for every a_i beyond them, as in networked systems), and otherwise the gradient of
the neighbourhood's share of the team's reward.
"""

from __future__ import annotations

import numpy as np

from dgtd.samples import added, namespace


def mean_step(k):
    """1 / sqrt(1 + k / 100): the step at k of the running averages (the average objective's mu_i) and, over |f|^2,
    of the team-reward regression; the first sample taken whole, then a window that widens as sqrt(k)."""
    return 1.0 / np.sqrt(1.0 + np.asarray(k, dtype=np.float64) / 100.0)


def regression_rate(k, n_agents: int, features_norm2=1.0):
    """nu_k = mean_step(k) / |f(s, a)|^2, with |f|^2 = N |g(s)|^2 (``features_norm2`` |g|^2: 1 on a model)."""
    return mean_step(k) / (n_agents * features_norm2)


def regression_step(nu, r, rhat):
    """nu (r_i - rhat_i): how far the estimate moves along f(s, a) on the agent's own reward."""
    return nu * (r - rhat)


def mean_update(step, x, mean):
    """step (x - mean): a running average's move towards a new sample."""
    return step * (x - mean)


def estimate(lam: np.ndarray, a: np.ndarray, g: np.ndarray, n_actions: int) -> np.ndarray:
    """rhat (B, n) = lambda_i^T f(s, a) of every agent held here: ``lam`` (B, n, N A m) in blocks (agent j, its
    action, m), ``a`` (B, N) every agent's action, ``g`` (B,) the index of a one-hot g(s) or (B, m) the features."""
    xp = namespace(lam)
    B, n, N = lam.shape[0], lam.shape[1], a.shape[1]
    if g.ndim == 1:
        at = positions(a, g, n_actions, lam.shape[2] // (N * n_actions))
        return xp.take_along_axis(lam, xp.broadcast_to(at[:, None, :], (B, n, N)), axis=-1).sum(-1)
    b, i, j = np.arange(B)[:, None, None], np.arange(n)[None, :, None], np.arange(N)[None, None, :]
    picked = lam.reshape(B, n, N, n_actions, -1)[b, i, j, a[:, None, :]]  # (B, n, N, m): each agent's block
    return (picked * g[:, None, None, :]).sum(axis=(2, 3))


def add_regression(into: np.ndarray, a: np.ndarray, g: np.ndarray, n_actions: int, step: np.ndarray) -> np.ndarray:
    """``into`` (B, n, N A m) plus step_bi f(s, a) for every agent held here (``step`` (B, n): `regression_step`);
    NumPy's in place, JAX's new (`dgtd.samples.added`)."""
    B, n, N = into.shape[0], into.shape[1], a.shape[1]
    b, i = np.arange(B)[:, None, None], np.arange(n)[None, :, None]
    if g.ndim == 1:
        ones = positions(a, g, n_actions, into.shape[2] // (N * n_actions))[:, None, :]
        return added(into, (b, i, ones), step[:, :, None])
    blocks = into.reshape(B, n, N, n_actions, -1)  # (NumPy's a view: added to in place)
    own = (b, i, np.arange(N)[None, None, :], a[:, None, :])
    return added(blocks, own, step[:, :, None, None] * g[:, None, None, :]).reshape(into.shape)


def positions(a: np.ndarray, s: np.ndarray, n_actions: int, m: int) -> np.ndarray:
    """(B, N): where f(s, a)'s ones lie for a one-hot g(s) = e_s of length m: (j A + a_j) m + s."""
    return (np.arange(a.shape[1]) * n_actions + a) * m + s[:, None]


def neighbourhood_slots(dst: np.ndarray, src: np.ndarray, local: np.ndarray) -> tuple:
    """(members (n, K), arcs (n, K), valid (n, K)) of the agents ``local`` of a graph's arcs src -> dst: slot 0 the
    agent itself (arc -1), slots 1.. its neighbours in the arcs' order, padded (valid False) to K = 1 + the largest
    number of neighbours."""
    order = np.argsort(dst, kind="stable")
    counts = np.bincount(dst, minlength=int(local.max(initial=-1)) + 1)
    starts = np.concatenate([[0], np.cumsum(counts)])
    K = 1 + int(counts[local].max(initial=0))
    members, arcs = np.tile(local[:, None], (1, K)), np.full((len(local), K), -1)
    valid = np.arange(K)[None, :] <= counts[local][:, None]
    for slot in range(1, K):
        has = valid[:, slot]
        arcs[has, slot] = order[starts[local[has]] + slot - 1]
        members[has, slot] = src[arcs[has, slot]]
    return members, arcs, valid


def slot_predictions(lam: np.ndarray, a: np.ndarray, g: np.ndarray) -> np.ndarray:
    """lambda_ik^T g(s) e_{a_i} (B, n, K) of every slot of every agent held here: ``lam`` (B, n, K, A, m), ``a``
    (B, n) each one's own action, ``g`` (B,) the index of a one-hot g(s) or (B, m) the features."""
    B, n = a.shape
    rows = lam[np.arange(B)[:, None], np.arange(n)[None, :], :, a]  # (B, n, K, m)
    if g.ndim == 1:
        return np.take_along_axis(rows, g[:, None, None, None], axis=-1)[..., 0]
    return (rows * g[:, None, None, :]).sum(-1)


def add_slots(into: np.ndarray, a: np.ndarray, g: np.ndarray, step: np.ndarray) -> np.ndarray:
    """``into`` (B, n, K, A, m) plus step_bik g(s) e_{a_i} for every slot (``step`` (B, n, K): `regression_step`
    where the slot's reward was heard, 0 elsewhere)."""
    B, n = a.shape
    b, i = np.arange(B)[:, None], np.arange(n)[None, :]
    if g.ndim == 1:
        into[b, i, :, a, g[:, None]] += step
    else:
        into[b, i, :, a] += step[..., None] * g[:, None, None, :]
    return into
