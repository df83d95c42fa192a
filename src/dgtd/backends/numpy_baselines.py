"""NumPy reference block kernels of the baselines (same contract as `dgtd.backends.numpy_ref.dgtd_block`).

Each advances all seeds and agents over steps [k0, k0 + T) with the algorithm's pure update function;
only the time loop is in Python.
"""

from __future__ import annotations

import numpy as np

from dgtd.algorithms import consensus_td0, gtd2, local, pd_td, tdc, td0
from dgtd.run.sampling import Block


def _sample(ctx, blk: Block, t: int):
    """phi, phi_next (B, n_obs, q), r (B, N), ratio (B, n_obs) of step t of the block."""
    s, a, sn = blk.s[t], blk.a[t], blk.s_next[t]
    return ctx.Phi[s], ctx.Phi[sn], blk.r[t], ctx.ratio[s, a]


def _advance(ctx, state, sums, k0: int, alphas, blk: Block, step):
    """Run ``step(state, t, phi, phi_next, r, ratio, alpha)`` over the block, summing the estimate first."""
    sums = {k: v.copy() for k, v in sums.items()}
    estimate = ctx.algorithm.estimate
    for t in range(len(alphas)):
        sums["all"] += estimate(state)
        state = step(state, t, *_sample(ctx, blk, t), alphas[t])
    return state, sums


def td0_block(ctx, state, sums, k0, alphas, blk):
    g = ctx.gamma
    return _advance(ctx, state, sums, k0, alphas, blk,
                    lambda st, t, p, pn, r, rho, a: td0.update(st, p, pn, r, rho, a, g))


def gtd2_block(ctx, state, sums, k0, alphas, blk):
    g, eta = ctx.gamma, ctx.algorithm.eta
    return _advance(ctx, state, sums, k0, alphas, blk,
                    lambda st, t, p, pn, r, rho, a: gtd2.update(st, p, pn, r, rho, a, eta, g))


def tdc_block(ctx, state, sums, k0, alphas, blk):
    g, eta = ctx.gamma, ctx.algorithm.eta
    return _advance(ctx, state, sums, k0, alphas, blk,
                    lambda st, t, p, pn, r, rho, a: tdc.update(st, p, pn, r, rho, a, eta, g))


def local_block(ctx, state, sums, k0, alphas, blk):
    g, eta = ctx.gamma, ctx.algorithm.eta
    return _advance(ctx, state, sums, k0, alphas, blk,
                    lambda st, t, p, pn, r, rho, a: local.update(st, p, pn, r, rho, a, eta, g))


def _masks(ctx, blk: Block, t: int) -> np.ndarray:
    """Edges up at step t, (B, E) bool (all up on a fixed graph)."""
    if blk.up is not None:
        return blk.up[t]
    return np.ones((blk.r.shape[1], ctx.network.n_edges), dtype=bool)


def consensus_td0_block(ctx, state, sums, k0, alphas, blk):
    g, edges, N = ctx.gamma, ctx.network.base.edges, ctx.network.n_nodes

    def step(st, t, p, pn, r, rho, a):
        W = consensus_td0.metropolis_weights(edges, _masks(ctx, blk, t), N)
        return consensus_td0.update(st, p, pn, r, rho, lambda X: ctx.lap(X, W), a, g)

    return _advance(ctx, state, sums, k0, alphas, blk, step)


def pd_td_block(ctx, state, sums, k0, alphas, blk):
    g, eta = ctx.gamma, ctx.algorithm.eta

    def step(st, t, p, pn, r, rho, a):
        mask = None if blk.up is None else blk.up[t]
        return pd_td.update(st, p, pn, r, rho, lambda X: ctx.lap(X, mask), a, g, eta)

    return _advance(ctx, state, sums, k0, alphas, blk, step)


BLOCKS = {
    "td0": td0_block,
    "gtd2": gtd2_block,
    "tdc": tdc_block,
    "local": local_block,
    "consensus-td0": consensus_td0_block,
    "pd-td": pd_td_block,
}
