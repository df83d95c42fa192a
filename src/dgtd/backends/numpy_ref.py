"""Plain NumPy reference kernels: the readable version every faster backend is tested against.

A kernel advances all seeds and agents over a block of steps [k0, k1) from that block's uniforms; the
uniforms become samples here with the same arithmetic as in the compiled kernels (`alias_pick`).
"""

from __future__ import annotations

import numpy as np

from dgtd.algorithms import dgtd as dgtd_alg
from dgtd.run.sampling import alias_pick, reward_from_uniform


def pick_states(ctx, u_state: np.ndarray, current: np.ndarray | None):
    """(s, a, s') of shape u_state[..., 0] from the state uniforms; i.i.d. uses u[..., 0] for s ~ d."""
    if current is None:
        K = ctx.tables.d_prob.shape[0]
        shape = u_state.shape[:-1]
        s = alias_pick(np.broadcast_to(ctx.tables.d_prob, shape + (K,)),
                       np.broadcast_to(ctx.tables.d_alias, shape + (K,)), u_state[..., 0])
    else:
        s = current
    idx = alias_pick(ctx.tables.sa_prob[s], ctx.tables.sa_alias[s], u_state[..., -1])
    S = ctx.n_states
    return s, idx // S, idx % S


def rewards(ctx, s: np.ndarray, a: np.ndarray, u_reward) -> np.ndarray:
    """r (..., N): agent i's reward at its observation (s_i, a_i); shared observations broadcast."""
    N = ctx.n_agents
    if s.shape[-1] == N:
        mean = ctx.R_sample[np.arange(N), s, a]
    else:
        mean = np.moveaxis(ctx.R_sample[:, s[..., 0], a[..., 0]], 0, -1)
    return reward_from_uniform(mean, ctx.sigma, ctx.reward_noise, u_reward)


def dgtd_block(ctx, state, sums, k0: int, alphas: np.ndarray, U: dict, current):
    """Advance Algorithm 1 over steps k0 .. k0 + len(alphas) - 1; returns (state, sums, current)."""
    T = len(alphas)
    markov = current is not None
    if not markov:
        s_all, a_all, sn_all = pick_states(ctx, U["state"], None)
    for t in range(T):
        k = k0 + t
        if markov:
            s, a, sn = pick_states(ctx, U["state"][t], current)
            current = sn
        else:
            s, a, sn = s_all[t], a_all[t], sn_all[t]
        r = rewards(ctx, s, a, U["reward"][t] if "reward" in U else None)
        mask = ctx.network.masks_from_uniforms(U["edge"][t]) if "edge" in U else None
        add_to_sums(ctx, sums, state.w, k)
        state = dgtd_alg.update(
            state, ctx.Phi[s], ctx.Phi[sn], r, ctx.ratio[s, a], lambda X: ctx.lap(X, mask),
            alphas[t], ctx.gamma, ctx.algorithm.kappa, ctx.algorithm.rho, ctx.boxes,
        )
    return state, sums, current


def add_to_sums(ctx, sums: dict, w: np.ndarray, k: int) -> None:
    """Running sums of w_k for the averaged iterates: all k (`prop:convergence1`) and k >= tail_start."""
    sums["all"] += w
    if k >= ctx.tail_start:
        sums["tail"] += w
