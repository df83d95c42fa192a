"""Where a run's agents are held, and what the run loop asks of it: all in this process (`Whole`), or spread over
the ranks of an MPI job (`dgtd.backends.mpi.Ranks`, the same methods; `layout_for` chooses). The run loop holds the
rows ``agents`` of every per-agent array and the arcs ``arc_ids`` of the channel's state, steps them with the
layout's ``kernel``, draws its samples from the layout's share of the source (`local`), and combines what it holds
through these methods (the worst agent, ordered sums, whether any seed diverged, every agent's rows on the process
that writes), so that its metrics and checkpoints are the same numbers however the agents are laid out. The run loop
never names the MPI runtime: this module does, once."""

from __future__ import annotations

import warnings

import numpy as np

from dgtd.problems.exact import ordered_consensus_error, tree_sum


class Whole:
    """Every agent in this process, in its own numbering (``agents`` None); sums over the agents taken in the
    storage order of the compiled kernels (`dgtd.backends.compiled.graph.storage_order`), the order the ranks hold
    them in."""

    agents = arc_ids = None
    root = True  # this process writes the results
    asynchronous = False
    block_budget = 1 << 24  # numbers a block of a kernel that draws its own samples may touch (`block_steps`)

    def __init__(self, ctx, backend: str):
        from dgtd.backends.compiled.graph import storage_order

        order = storage_order(ctx)
        self.order = None if order is None else order[0]
        self.arcs = ctx.arcs
        self.kernel = kernel_for(backend, ctx.algorithm, ctx.channel)

    def local(self, source):
        """The source of the samples of the agents held here: all of them."""
        return source

    def rows(self, x: np.ndarray) -> np.ndarray:
        return x

    def max(self, x: np.ndarray) -> np.ndarray:
        return x

    def worst(self, x: np.ndarray) -> np.ndarray:
        """The worst agent's value (B,) of a per-agent quantity (B, n)."""
        return self.max(x.max(-1))

    def any(self, x: np.ndarray) -> np.ndarray:
        return x

    def total(self, x: np.ndarray) -> np.ndarray:
        """Whole numbers summed over the processes: this one's alone."""
        return x

    def collect(self, x) -> list:
        """Every process's ``x`` (a few numbers), on the one that writes: this one's."""
        return [x]

    def tree_sum(self, x: np.ndarray) -> np.ndarray:
        """x (B, N, ...) summed over the agents up their fixed tree in storage order (`dgtd.problems.exact.tree_sum`),
        as the ranks sum it."""
        stored = self.order is not None and x.shape[1] == len(self.order)  # (a centralised learner: one row)
        return tree_sum(x[:, self.order] if stored else x)

    def consensus(self, W: np.ndarray) -> np.ndarray:
        """The consensus error (B,) of the agents' estimates W (B, N, q) (`ordered_consensus_error`)."""
        return ordered_consensus_error(W, W.shape[1], self.tree_sum)

    def init_channel(self, channel, seeds: int, seed: int):
        return channel.init(seeds, self.arcs, seed)

    def whole(self, x: np.ndarray, axis: int = 1) -> np.ndarray:
        return x

    def whole_arcs(self, x: np.ndarray, n_arcs: int) -> np.ndarray:
        return x

    def reported(self, x: np.ndarray) -> np.ndarray:
        return x

    def shard(self) -> dict:
        return {}

    def message_ages(self, restore: dict | None = None) -> dict:
        """The ages of the messages used (asynchronous ranks only): none here."""
        return {}


def layout_for(ctx, settings, resume: dict | None = None):
    """The run's layout: its agents spread over the ranks of an mpiexec job where the algorithm spreads
    (`dgtd.backends.mpi.Ranks`, asynchronous where ``settings`` say so; ``resume`` a snapshot whose message ages it
    continues), else `Whole`. What the layout cannot run is refused first, in one line the same on every rank."""
    from dgtd.backends import mpi

    algorithm = ctx.algorithm
    mpi.check_supported(algorithm, ctx.channel, ctx.n_agents, settings.backend, settings.asynchronous)
    if settings.backend == "jax":
        from dgtd.backends import jax as on_jax

        on_jax.check_supported(ctx.channel)
    if mpi.spreads(algorithm):
        return mpi.Ranks.of(ctx, settings.backend, settings.asynchronous, settings.staleness, resume)
    return Whole(ctx, settings.backend)


def spread_over(algorithm, available: int | None) -> tuple[int, int, int | None]:
    """(the ranks a run of ``algorithm`` spreads its agents over, those on this machine, the memory they have free
    there, ``available`` in one process): for the memory check, the same verdict on every rank (the tightest
    machine's share a rank, `dgtd.backends.mpi.tightest_share`). (1, 1, available) in one process, or where every rank
    runs the algorithm whole."""
    from dgtd.backends import mpi

    if not mpi.spreads(algorithm):
        return 1, 1, available
    here, least = mpi.on_this_machine(), mpi.tightest_share(available)
    return mpi.size(), here, None if least is None else here * least


def kernel_for(backend: str, algorithm, channel=None):
    """The block kernel of ``algorithm`` over ``channel`` on ``backend`` (`dgtd.backends.reference.run_block`
    contract): the compiled driver where the algorithm has a compiled step and the channel a compiled twin; else the
    reference, with a one-line notice."""
    from dgtd.backends.reference import run_block

    if backend == "numpy":
        return run_block
    if backend == "jax":
        from dgtd.backends import jax as on_jax

        return on_jax.run_block
    from dgtd.backends.compiled import fallback
    from dgtd.backends.compiled import run_block as compiled

    if reason := fallback(algorithm, channel):
        warnings.warn(reason, stacklevel=4)
        return run_block
    return compiled


class AllAgents:
    """Every agent of a learning run in this process: its rows are all of them, gathering them is nothing, and they
    hear over the whole network's arcs (``arcs``; None: none)."""

    root = True
    arc_ids = None  # (every arc's channel state, in order)

    def __init__(self, n_agents: int, arcs=None):
        from dgtd.channels import Arcs

        self.local = self.own_rows = np.arange(n_agents)
        self.arcs = Arcs.of(np.zeros((0, 2)), n_agents) if arcs is None else arcs
        self.edges = np.arange(self.arcs.n_arcs // 2)  # every edge's draws

    def init_channel(self, channel, seeds: int, seed: int):
        return channel.init(seeds, self.arcs, seed)

    def hear(self, channel, links, sent: dict, up):
        """(an `Inbox` of what every agent heard, the channel's new state): `dgtd.channels.Channel.deliver`."""
        return channel.deliver(links, self.arcs, sent, up)

    def reported(self, x: np.ndarray) -> np.ndarray:
        return x

    def gather(self, x: np.ndarray) -> np.ndarray:
        return x

    def gather_root(self, x: np.ndarray) -> np.ndarray | None:
        """Every agent's rows on the process that writes (None elsewhere): here, all of them."""
        return x

    def every(self, x: np.ndarray) -> np.ndarray:
        """``x`` (bools) true on every process: this one's."""
        return x

    def shard(self) -> dict:
        """The ids of the rows a checkpoint written here holds: every agent's, in order (none to name)."""
        return {}


def learner_layout(n_agents: int, arcs=None, halo: bool = False):
    """Where a learning run's agents are held, and the arcs ``arcs`` (the whole network's; None: none) they hear
    over: spread over the ranks of an mpiexec job of more than one rank (`dgtd.backends.mpi.LearnerRanks`, the run's
    partition; ``halo`` where agents weigh what they hear by their neighbours' counts), else all here (`AllAgents`)."""
    from dgtd.backends import mpi

    return mpi.LearnerRanks(n_agents, arcs, halo) if mpi.spread() else AllAgents(n_agents, arcs)
