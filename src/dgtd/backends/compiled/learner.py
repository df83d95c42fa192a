"""The learners' compiled arithmetic (`dgtd learn --backend numba`): the agents' part of a learning step of
`dgtd.run.learn`, in numba, with each critic's update made from its one definition (`dgtd.algorithms.base`), as the
evaluation driver's (`dgtd.backends.compiled.step.algorithm_space`).

What stays in Python is what is not per agent: the actions' draw and the environment's step (a problem file's joint
table, a factored MDP's groups: O(B N) a step), and the channel's `deliver` (which arcs delivered, the counts of
messages and bits: exactly the NumPy run's). Per agent, in three kernels:

- `_sample_block` (every step): agent i's estimate of the team's reward and its regression step (networked), its TD
  error or advantage, its critic's sample directions added to the round's, and its actor's step beta_k delta psi;
- `aggregates` (a round's end): for every agent held here, the Laplacian or Metropolis sum of what it heard over the
  arcs that delivered, the critic's messages and the team-reward estimates alike (O(arcs x message), never a dense
  N x N matrix);
- `_move_block` (a round's end): the critic's ``feature`` on the round's mean directions and the aggregates; an
  asleep agent keeps its state.

The same arithmetic as the NumPy run, summed in another order: the two agree to rounding (tested to 1e-12).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from dgtd.algorithms.actor import score_step, td_error
from dgtd.algorithms.team_reward import regression_step
from dgtd.backends.compiled.driver import compiled_copy
from dgtd.backends.compiled.simd import dot
from dgtd.backends.compiled.step import (
    ADD_TERMS,
    COEFFICIENTS,
    FEATURE,
    LOAD_HEARD,
    LOAD_STATE,
    LOAD_TERMS,
    PRODUCTS,
    STEPS_OF,
    STORE,
    TERMS_OF,
    TRANSMIT,
    Features,
    algorithm_space,
    step_of,
)

__all__ = ["LearnerKernels", "aggregates", "learner_fallback"]


def _sample_block(
    p,
    own,
    sent,
    w,
    D,
    theta,
    pending_theta,
    lam,
    pending_lam,
    feat,
    s,
    a,
    local,
    r,
    r_critic,
    r_actor,
    scal,
    baseline,
    rhat_out,
):
    """Step k's sample for every seed b and agent i held here (rows ``local`` of every agent's ``a``): ``scal`` =
    (beta_k, nu_k, gamma, S, A, state values?, the entropy bonus) (`dgtd.run.learn`'s docstring: rhat, the
    regression, delta or the action-value advantage, the critic's directions into D[:, b n + i], the actor's into
    pending_theta); the advantage's ``baseline`` (B, n) subtracted from rhat (the average objective's mu~_i),
    rhat written to ``rhat_out``: ``r_actor`` (B, n) where ``lam`` is empty (the team's reward as the agent knows it
    without Zhang et al.'s regression: its own, the team's, or its neighbourhood's estimate)."""
    beta, nu, gamma, S, A, state_values, tau = scal
    B, n, q, N = theta.shape[0], theta.shape[1], w.shape[2], a.shape[1]
    networked = lam.shape[2] > 0
    for b in range(B):
        sb, x0, x1 = s[b], 2 * b, 2 * b + 1  # the seed's feature rows: phi(s) and phi(s') (or E_pi f(s', .))
        for i in range(n):
            agent = local[i]
            if state_values:
                rhat = r_actor[b, i]
                if networked:  # lambda_i^T f(s, a), f's ones at (j, a_j, s) (`team_reward.positions`)
                    rhat = 0.0
                    for j in range(N):
                        rhat += lam[b, i, (j * A + a[b, j]) * S + sb]
                    g = _regression_step(nu, r[b, i], rhat)
                    for j in range(N):
                        pending_lam[b, i, (j * A + a[b, j]) * S + sb] += g
                rhat_out[b, i] = rhat
                ahead: float = dot(feat.Phi, x1, w, (b, i), q)  # type: ignore[call-arg]
                here: float = dot(feat.Phi, x0, w, (b, i), q)  # type: ignore[call-arg]
                delta = _td_error(rhat, baseline[b, i], gamma, ahead, here)
            else:  # w_i[i, s, a_i] - sum_c pi_i(c | s) w_i[i, s, c]: the advantage on additive features
                o = agent * S * A + sb * A
                delta = w[b, i, o + a[b, agent]] - _expected(theta, b, i, sb, w, o)
            c = COEFFICIENTS(p, PRODUCTS(feat, x0, x1, own, sent, b, i, q), r_critic[b, i], 1.0, gamma)
            at = b * n + i
            for f in range(q):
                ADD_TERMS(D, at, f, TERMS_OF(p, feat.Phi[x0, f], feat.Phi[x1, f], c, gamma))
            _actor_step(theta, pending_theta, b, i, sb, a[b, agent], beta, delta, tau)


@njit(cache=True, inline="always")
def _softmax_sum(theta, b, i, s):
    """(the largest entry of theta_i's row s, sum_c exp(theta - largest)): the softmax's normaliser."""
    A = theta.shape[3]
    top = theta[b, i, s, 0]
    for c in range(1, A):
        top = max(top, theta[b, i, s, c])
    total = 0.0
    for c in range(A):
        total += np.exp(theta[b, i, s, c] - top)
    return top, total


@njit(cache=True, inline="always")
def _expected(theta, b, i, s, w, o):
    """sum_c pi_i(c | s) w[b, i, o + c] over the actions agent i has (probability above 0)."""
    top, total = _softmax_sum(theta, b, i, s)
    acc = 0.0
    for c in range(theta.shape[3]):
        pi = np.exp(theta[b, i, s, c] - top) / total
        if pi > 0.0:
            acc += pi * w[b, i, o + c]
    return acc


# the learners' arithmetic, one definition each (`dgtd.algorithms.actor`, `dgtd.algorithms.team_reward`)
_td_error, _score_step, _regression_step = (
    njit(cache=True, inline="always")(f) for f in (td_error, score_step, regression_step)
)


@njit(cache=True, inline="always")
def _actor_step(theta, pending, b, i, s, a, beta, delta, tau):
    """pending[b, i, s] += `score_step` on each action agent i has (theta finite) at its state s."""
    top, total = _softmax_sum(theta, b, i, s)
    log_pi = theta[b, i, s, a] - top - np.log(total)
    for c in range(theta.shape[3]):
        x = theta[b, i, s, c]
        if np.isfinite(x):
            pending[b, i, s, c] += _score_step(
                beta, delta, log_pi, tau, 1.0 if c == a else 0.0, np.exp(x - top) / total
            )


@njit(cache=True)
def aggregates(x, heard, weights, degrees, metropolis, indptr, arcs, src, local, out):
    """out[b n + i] = sum over the arcs a = j -> agent local[i] that delivered (heard[b, a] > 0, in the order of
    ``arcs[indptr[i]:indptr[i + 1]]``) of c_a (x[b, local[i]] - x[b, j]): c_a = W_ij = 1 / (1 + max(d_i, d_j))
    where ``metropolis`` (``degrees`` (B, N) the d's), else heard[b, a] weights[a] (the Laplacian's)."""
    B, n, q = x.shape[0], local.shape[0], x.shape[2]
    for b in range(B):
        for i in range(n):
            at, agent = b * n + i, local[i]
            for f in range(q):
                out[at, f] = 0.0
            for k in range(indptr[i], indptr[i + 1]):
                arc = arcs[k]
                h = heard[b, arc]
                if h == 0.0:
                    continue
                j = src[arc]
                if metropolis:
                    c = h / (1.0 + max(degrees[b, agent], degrees[b, j]))
                else:
                    c = h * weights[arc]
                for f in range(q):
                    out[at, f] += c * (x[b, agent, f] - x[b, j, f])


def _move_block(p, own, sent, out, L, D, awake, alpha):
    """The critics of every seed and agent held here moved by the round's mean directions D and the aggregates L
    (rows b n + i), their messages written to ``out``; an asleep agent keeps its state and sends it again."""
    B, n, q, M = sent.shape[1], sent.shape[2], sent.shape[3], sent.shape[0]
    steps = STEPS_OF(p, alpha)
    for b in range(B):
        for i in range(n):
            at = b * n + i
            if not awake[b, i]:
                for m in range(M):
                    for f in range(q):
                        out[m, b, i, f] = sent[m, b, i, f]
                continue
            for f in range(q):
                new = FEATURE(p, LOAD_STATE(own, sent, b, i, f), LOAD_HEARD(L, at, f), LOAD_TERMS(D, at, f), steps)
                STORE(own, out, b, i, f, new, TRANSMIT(new))


_KERNELS: dict = {}


def _kernels(critic) -> tuple:
    """(`_sample_block`, `_move_block`) compiled for the critic's class, once per process, cached on disk."""
    compiled = step_of(critic)
    assert compiled is not None, "learner_fallback sends a critic without the one definition to NumPy"
    if compiled.key not in _KERNELS:
        space = dict(globals()) | algorithm_space(critic)[0]  # the algorithm's functions in place of the placeholders
        sample = compiled_copy(_sample_block, space, compiled.key, compiled.cache)
        move = compiled_copy(_move_block, space, compiled.key, compiled.cache)
        _KERNELS[compiled.key] = (sample, move)
    return _KERNELS[compiled.key]


def learner_fallback(critic, channel) -> str | None:
    """Why a learning run with ``critic`` over ``channel`` takes the NumPy backend (one line), or None."""
    if step_of(critic) is None:
        return f"the critic {critic.name!r} writes update alone: the learners run on the NumPy backend"
    if channel.holds:
        return (
            f"links that hold late, asleep or compressed copies ({channel.describe()}) have no compiled twin for "
            "learners: they run on the NumPy backend"
        )
    return None


class LearnerKernels:
    """The compiled kernels of one learning run: its critic's, and the arcs ``arcs`` into the agents held here
    (``local``, their ids; ``rows`` theirs in what they hear, over which ``arcs`` run: `dgtd.run.layout`), grouped by
    receiver in the order of the arcs (as `dgtd.channels.Arcs.into` adds them)."""

    def __init__(self, critic, arcs, local: np.ndarray, rows: np.ndarray):
        self.critic = critic
        self.sample_block, self.move_block = _kernels(critic)
        self.own_names = tuple(f for f in critic.init(1, 1, 1)._fields if f not in critic.messages)
        order = np.argsort(arcs.dst, kind="stable")
        mine = np.isin(arcs.dst[order], rows)
        self.arcs_in = np.ascontiguousarray(order[mine], np.int64)
        counts = np.bincount(np.searchsorted(rows, arcs.dst[self.arcs_in]), minlength=len(rows))
        self.indptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        self.src = np.ascontiguousarray(arcs.src, np.int64)
        self.local = np.ascontiguousarray(local, np.int64)
        self.rows = np.ascontiguousarray(rows, np.int64)
        self.p = critic.params()

    def stacks(self, state) -> tuple[np.ndarray, np.ndarray]:
        """(own (K, B, n, q), sent (M, B, n, q)): the critic's state as the compiled step reads it."""
        w = self.critic.estimate(state)
        own = [getattr(state, f) for f in self.own_names]
        sent = list(self.critic.sends(state).values())
        return _stack(own, w.shape), _stack(sent, w.shape)

    def state_of(self, template, own: np.ndarray, sent: np.ndarray):
        """The critic's state (a NamedTuple like ``template``) from its stacks."""
        values = dict(zip(self.own_names, own)) | dict(zip(self.critic.messages, sent))
        return template._make(values[f] for f in template._fields)

    def sample(self, state, pending: dict, theta, lam, rows, s, a, r, r_critic, r_actor, scal, baseline, rhat) -> None:
        """A step's sample added to the round's sums in ``pending`` (`_sample_block`); the estimates of the team's
        reward written to ``rhat`` (B, n)."""
        own, sent = self.stacks(state)
        w = self.critic.estimate(state)
        B, n, q = w.shape
        if "D" not in pending:  # a round's first step
            n_terms = len(self.critic.terms(self.p, 1.0, 1.0, self._coefficients(), 1.0))
            pending["D"], pending["theta"] = np.zeros((n_terms, B * n, q)), np.zeros_like(theta)
            if lam is not None:
                pending["lam"] = np.zeros_like(lam)
        empty, none = np.zeros(0), np.zeros((B, n, 0))
        self.sample_block(
            self.p, own, sent, np.ascontiguousarray(w), pending["D"], theta, pending["theta"],
            none if lam is None else lam, pending.get("lam", none),
            Features(np.ascontiguousarray(rows), False, empty.astype(np.int64), empty.astype(np.int64), empty),
            np.ascontiguousarray(s, np.int64), np.ascontiguousarray(a, np.int64), self.local,
            np.ascontiguousarray(r, np.float64), np.ascontiguousarray(r_critic, np.float64),
            np.ascontiguousarray(r_actor, np.float64), scal,
            np.ascontiguousarray(baseline, np.float64), rhat,
        )  # fmt: skip

    def _coefficients(self) -> tuple:
        cls = type(self.critic)
        return cls.coefficients(self.p, (1.0,) * len(cls.reads), 1.0, 1.0, 1.0)

    def mixed(self, inbox, x: np.ndarray, metropolis: bool) -> np.ndarray:
        """(B, n, q): every agent held here's aggregate of ``x`` (every row's of what they hear, (B, rows, q)) over
        the arcs heard."""
        B, q = x.shape[0], x.shape[2]
        out = np.zeros((B * len(self.rows), q))
        weights = np.ones(self.src.shape[0]) if inbox.weights is None else np.asarray(inbox.weights, np.float64)
        degrees = np.ascontiguousarray(inbox.count(), np.float64) if metropolis else np.zeros((B, 0))
        aggregates(
            np.ascontiguousarray(x, np.float64), np.ascontiguousarray(inbox.heard), weights, degrees, metropolis,
            self.indptr, self.arcs_in, self.src, self.rows, out,
        )  # fmt: skip
        return out.reshape(B, len(self.rows), q)

    def move(self, state, inbox, D: np.ndarray, alpha: float):
        """The critics' new state at a round's end (`_move_block`): the mean of the round's directions ``D`` (terms,
        B n, q) and what they heard (``inbox``, every agent's: `dgtd.channels.Inbox`)."""
        own, sent = self.stacks(state)
        B, n = sent.shape[1], sent.shape[2]
        metropolis = self.critic.mixing == "metropolis"
        L = np.stack([self.mixed(inbox, inbox.sent[m], metropolis) for m in self.critic.messages]).reshape(
            len(self.critic.messages), B * n, -1
        ) if self.critic.messages else np.zeros((0, B * n, sent.shape[3]))  # fmt: skip
        D = np.ascontiguousarray(D)
        awake = np.ones((B, n), bool) if inbox.awake is None else np.ascontiguousarray(inbox.awake[:, self.rows])
        out = np.empty_like(sent)
        self.move_block(self.p, own, sent, out, L, D, awake, float(alpha))
        return self.state_of(state, own, out)


def _stack(arrays: list, shape: tuple) -> np.ndarray:
    if not arrays:
        return np.zeros((0, *shape))
    return np.ascontiguousarray(np.stack([np.asarray(x, np.float64) for x in arrays]))
