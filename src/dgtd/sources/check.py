"""A conformance check for sample sources (`dgtd.samples.Source`), as PettingZoo's ``parallel_api_test`` is for
environments: what every source must do for the run loop, the backends and the checkpoints to treat it alike.

`check_source` runs a source built by ``make(seed, seed_ids)`` and raises an `AssertionError` naming the first
broken rule:

- shapes and types: s, a, s' (T, B, n) integers with n = N or 1, r (T, B, N) finite floats, ``up`` (T, B, E) booleans
  over the network's edges (None only on a network whose every edge is always up), indices inside the block's
  ``table`` (or the model's states);
- each seed its own stream: seed k's samples are the same whether it runs alone or beside others;
- blocks concatenate: T steps in one block are the steps of two blocks of T1 and T - T1;
- resume: after ``set_state`` of a state taken between blocks, the next block is the one that followed (a simulator
  whose state cannot be saved, ``resumable`` False, refuses in one line instead);
- the same samples on both backends, where a source draws them with either (a model's): ``twin``'s blocks are equal;
- links from the run's network: over the steps drawn, edge e is up at a frequency within ``LINK_SIGMAS`` standard
  errors of its probability p_e (a random-edge network; a proximity network's links follow the agents' positions and
  are checked for shape only).
"""

from __future__ import annotations

import numpy as np

from dgtd.samples import Block

LINK_SIGMAS = 5.0  # a seeded check: 5 binomial standard errors, so a source that draws its links right passes


def check_source(
    make,
    network,
    n_agents: int,
    steps: int = 400,
    seed: int = 7,
    seeds: int = 3,
    random_links: bool = True,
    twin=None,
    resumable: bool = True,
) -> None:
    """Check the source ``make(seed, seed_ids)`` of a run over ``network`` (its ``base`` graph's edges, and for
    ``random_links`` its edge probabilities ``p``) with ``n_agents`` agents, on ``steps`` steps of ``seeds`` seeds;
    ``twin(seed, seed_ids)``: the same source on the other backend."""
    ids = list(range(seeds))
    many = make(seed, ids)
    many.start()
    whole = many.next_block(steps)
    _check_shapes(whole, steps, seeds, n_agents, network)

    alone = make(seed, [ids[-1]])
    alone.start()
    _same(_seed(alone.next_block(steps), 0), _seed(whole, seeds - 1), f"seed {ids[-1]} alone and beside others")

    parts = make(seed, ids)
    parts.start()
    first = parts.next_block(steps // 3)
    state = parts.get_state()
    second = parts.next_block(steps - steps // 3)
    _same(_joined(first, second), whole, "one block and two blocks of the same steps")
    resumed = make(seed, ids)
    resumed.start()
    if resumable:
        resumed.set_state(state)
        _same(
            resumed.next_block(steps - steps // 3), second, "the block after a state was set and the one that followed"
        )
    else:
        from dgtd.errors import DgtdInputError

        try:
            resumed.set_state(state)
        except DgtdInputError:
            pass
        else:
            raise AssertionError("a source that cannot be resumed took a state without saying so")

    if twin is not None:
        other = twin(seed, ids)
        other.start()
        _same(other.next_block(steps), whole, "the two backends")

    if random_links and whole.up is not None:
        up = whole.up.reshape(-1, whole.up.shape[-1])
        p = np.broadcast_to(np.asarray(network.p, dtype=np.float64), (up.shape[1],))
        error = np.sqrt(p * (1 - p) / up.shape[0]) + 1e-12
        bad = np.flatnonzero(np.abs(up.mean(axis=0) - p) > LINK_SIGMAS * error)
        assert bad.size == 0, (
            f"edge {bad[0]} was up at {up[:, bad[0]].mean():.3f} of the steps, its probability is "
            f"{p[bad[0]]:.3f}: the links are not drawn from the run's network"
        )


def _check_shapes(blk: Block, T: int, B: int, N: int, network) -> None:
    n = blk.s.shape[2]
    for name in ("s", "a", "s_next"):
        x = getattr(blk, name)
        assert x.shape == (T, B, n) and np.issubdtype(x.dtype, np.integer), f"{name} is {x.shape} {x.dtype}"
    assert n in (1, N), f"observations per step: {n}, neither 1 (shared) nor N = {N}"
    assert blk.r.shape == (T, B, N) and np.isfinite(blk.r).all(), f"r is {blk.r.shape} or not finite"
    E = network.base.n_edges
    if blk.up is None:
        assert bool(getattr(network, "fixed", False)), "no links (up is None) on a network whose edges are not all up"
    else:
        assert blk.up.shape == (T, B, E) and blk.up.dtype == np.bool_, f"up is {blk.up.shape} {blk.up.dtype}"
    if blk.table is not None:
        rows = blk.table.phi.shape[0]
        assert max(blk.s.max(), blk.s_next.max()) < rows and min(blk.s.min(), blk.s_next.min()) >= 0, (
            "indices outside the block's table"
        )
        assert blk.table.ratio.shape[0] == rows and blk.table.continuing.shape == (rows,), "table rows disagree"


def _seed(blk: Block, b: int) -> dict:
    """Seed b's samples, as values (a block's indices into its own table are resolved)."""
    out = {"r": blk.r[:, b], "up": None if blk.up is None else blk.up[:, b]}
    for name in ("s", "s_next"):
        index = getattr(blk, name)[:, b]
        out[name] = index if blk.table is None else blk.table.phi[index]
    out["a"] = blk.a[:, b] if blk.table is None else blk.table.ratio[blk.s[:, b], 0]
    return out


def _joined(a: Block, b: Block) -> Block:
    """Two blocks as one (their tables stacked, the second's indices shifted)."""
    shift = 0 if a.table is None else a.table.phi.shape[0]
    table = None if a.table is None or b.table is None else type(a.table)(*map(np.concatenate, zip(a.table, b.table)))
    up = None if a.up is None else np.concatenate([a.up, b.up])
    return Block(
        np.concatenate([a.s, b.s + shift]),
        np.concatenate([a.a, b.a]),
        np.concatenate([a.s_next, b.s_next + shift]),
        np.concatenate([a.r, b.r]),
        up,
        table,
    )


def _same(a: Block | dict, b: Block | dict, what: str) -> None:
    if isinstance(a, Block):
        for k in range(a.r.shape[1]):
            _same(_seed(a, k), _seed(b, k), f"{what} (seed {k})")  # type: ignore[arg-type]
        return
    for name in a:
        x, y = a[name], b[name]
        if x is None or y is None:
            assert x is None and y is None, f"{name} differs between {what}"
        else:
            assert np.array_equal(x, y), f"{name} differs between {what}"
