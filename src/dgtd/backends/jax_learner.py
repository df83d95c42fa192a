"""The learners' arithmetic on JAX (`dgtd learn --backend jax`, the optional extra ``dgtd[jax]``): the agents' part of
a learning step of `dgtd.run.learn`, compiled by `jax.jit` in float64, on a GPU where JAX has one, else on the CPU.

It stands where `dgtd.backends.compiled.learner` (numba) stands, with the same three calls, and computes from the
one definition of each piece that the NumPy learners run: the critic's ``directions`` and ``moved``
(`dgtd.algorithms.base`), the actor's step and the action-value advantage (`dgtd.algorithms.actor`), the team-reward
regression (`dgtd.algorithms.team_reward`) and the neighbours' aggregates (`dgtd.channels.Inbox`):

- `JaxLearners.sample` (every step): each agent's estimate of the team's reward and its regression step (networked),
  its TD error or advantage, its critic's sample directions and its actor's step, added to the round's sums;
- `JaxLearners.mixed` and `JaxLearners.move` (a round's end): the Metropolis or Laplacian sums of what each agent
  heard over the arcs that delivered, and the critics moved by the round's mean directions and those sums.

What stays on the host is what is not per agent, as for numba: the actions' draw and the environment's step, and
the channel's `deliver` (which arcs delivered, the counts of messages and bits: the NumPy run's own). The arrays go
to the device and back each step (the learners' state is the run's NumPy state, checkpointed as it is): the same
numbers as NumPy and numba to rounding (tested to 1e-12), not a device-resident loop.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from dgtd.algorithms.actor import action_advantage, actor_increment, own_values, policy, td_error
from dgtd.algorithms.team_reward import add_regression, estimate, regression_step
from dgtd.backends.jax import _jax
from dgtd.channels.inbox import HeldRows, Inbox
from dgtd.samples import Sample

__all__ = ["JaxLearners"]


class JaxLearners:
    """The JAX arithmetic of one learning run: its critic's, over its arcs, for the agents held here (``local``, their
    ids; ``rows``, theirs in what they hear, over which ``arcs`` run: `dgtd.run.layout`)."""

    def __init__(self, critic, arcs, local: np.ndarray, rows: np.ndarray):
        self.critic, self.arcs = critic, arcs
        self.jnp = _jax().numpy
        self.local = self.jnp.asarray(np.asarray(local, np.int64))
        self.rows = self.jnp.asarray(np.asarray(rows, np.int64))
        self._sample, self._mixed, self._move = _compiled(critic, arcs)

    def sample(self, state, pending: dict, theta, lam, rows, s, a, r, r_critic, r_actor, scal, baseline, rhat) -> None:
        """A step's sample added to the round's sums in ``pending`` (`dgtd.backends.compiled.learner.LearnerKernels`'
        contract: ``rows`` phi(s), phi(s') of each seed in turn (2 B, q); ``scal`` (beta_k, nu_k, gamma, S, A, state
        values?, the entropy bonus)); the estimates of the team's reward written to ``rhat`` (B, n)."""
        beta, nu, gamma, S, A, state_values, tau = scal
        jnp, B = self.jnp, len(s)
        phi = rows.reshape(B, 2, 1, -1)
        d, dtheta, dlam, rhat_j = self._sample(
            _on(jnp, state), jnp.asarray(theta), None if lam is None else jnp.asarray(lam), jnp.asarray(phi[:, 0]),
            jnp.asarray(phi[:, 1]), jnp.asarray(s), jnp.asarray(a), self.local, jnp.asarray(r),
            jnp.asarray(r_critic), jnp.asarray(r_actor), jnp.asarray(baseline), beta, nu, gamma, tau, S, A,
            state_values,
        )  # fmt: skip
        for name, x in (("D", d), ("theta", dtheta), ("lam", dlam)):
            if x is not None:
                pending[name] = pending[name] + np.asarray(x) if name in pending else np.array(x)
        rhat[...] = np.asarray(rhat_j)

    def mixed(self, inbox, x: np.ndarray, metropolis: bool) -> np.ndarray:
        """(B, n, q): every agent held here's aggregate of ``x`` (every agent's, (B, N, q)) over the arcs heard."""
        jnp = self.jnp
        heard = jnp.asarray(inbox.heard)
        return np.asarray(self._mixed(jnp.asarray(x), heard, *_counts(jnp, inbox), self.rows, metropolis))

    def move(self, state, inbox, D: np.ndarray, alpha: float):
        """The critics' new state at a round's end: the mean of the round's directions ``D`` (terms, B, n, q) and what
        they heard (``inbox``, every agent's: `dgtd.channels.Inbox`)."""
        jnp = self.jnp
        sent = {m: jnp.asarray(inbox.sent[m]) for m in self.critic.messages}
        heard = jnp.asarray(inbox.heard)
        new = self._move(_on(jnp, state), jnp.asarray(D), sent, heard, *_counts(jnp, inbox), self.rows, alpha)
        return type(state)(*(np.array(x) for x in new))


def _on(jnp, state):
    return type(state)(*(jnp.asarray(x) for x in state))


def _counts(jnp, inbox) -> tuple:
    """(the arcs' weights, the agents' counts of what they heard where the inbox holds them: a rank's, whose ghosts'
    counts come from elsewhere), each None where the inbox has none."""
    return tuple(None if x is None else jnp.asarray(x) for x in (inbox.weights, inbox.degrees))


@lru_cache(maxsize=16)
def _compiled(critic, arcs) -> tuple:
    """(sample, mixed, move) of `JaxLearners` compiled for ``critic`` over ``arcs``, once per process."""
    jax = _jax()
    jnp = jax.numpy

    def sample(state, theta, lam, phi, phi_next, s, a, local, r, r_critic, r_actor, baseline, beta, nu, gamma, tau,
               S, A, state_values):  # fmt: skip
        B, n = theta.shape[:2]
        w = critic.estimate(state)  # (B, n, q)
        mine = a[:, local]
        rhat, dlam = r_actor, None
        if not state_values:  # the action-value critic's advantage on its additive features
            here = policy(theta[np.arange(B)[:, None], np.arange(n)[None, :], s[:, None]])
            delta = action_advantage(own_values(w, local, s, S, A), here, mine)
        else:
            if lam is not None:  # Zhang et al.'s regression of the agent's own reward over f(s, a)
                rhat = estimate(lam, a, s, A)
                dlam = add_regression(jnp.zeros_like(lam), a, s, A, regression_step(nu, r, rhat))
            delta = td_error(rhat, baseline, gamma, (w * phi_next).sum(-1), (w * phi).sum(-1))
        d = critic.directions(state, Sample(phi, phi_next, r_critic, jnp.ones((B, 1)), gamma))
        return jnp.stack(d), actor_increment(theta, s, mine, delta, beta, None, tau), dlam, rhat

    def mixed(x, heard, weights, degrees, rows, metropolis):
        inbox = Inbox(arcs, {"x": x}, heard, weights=weights, degrees=degrees)
        return (inbox.metropolis("x") if metropolis else inbox.laplacian("x"))[:, rows]

    def move(state, D, sent, heard, weights, degrees, rows, alpha):
        here = HeldRows(Inbox(arcs, sent, heard, weights=weights, degrees=degrees), rows)
        return critic.moved(state, tuple(D), here, alpha)

    return (
        jax.jit(sample, static_argnames=("tau", "S", "A", "state_values")),
        jax.jit(mixed, static_argnames=("metropolis",)),
        jax.jit(move),
    )
