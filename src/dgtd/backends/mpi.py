"""The agents of a run spread over the ranks of an MPI job (``mpiexec -n R dgtd run ...``): synchronously, or with
``--asynchronous`` ranks that do not wait for each other's messages (`dgtd.backends.mailbox`; then the exchange below
is its non-blocking messages).

Rank r holds a contiguous block of the agents in their storage order (`Partition`: the compiled kernels' order,
reverse Cuthill-McKee where it keeps more links local, split as evenly as it goes) and updates only those, with the
compiled kernels over its share (`compiled_block`, `dgtd.backends.share`) or the NumPy reference's arithmetic
(`run_block`), so that a run on R ranks gives the numbers of a one-process run of the same backend bit for bit. At
every step each rank sends the messages of its agents that another rank's agents hear (the links that cross ranks)
and receives those of its ghosts (the other ranks' agents its own hear), through one neighbourhood collective on a
distributed-graph communicator of the ranks whose agents are linked; links inside a rank cost nothing. Every random
number is keyed by what it is for (`dgtd.streams`), so each rank draws only its own agents' and ghosts' samples and
the events of the links into them (`local_source`, the channel over `Partition.arcs`): O(N / R + boundary) numbers a
step, the numbers a one-process run draws for them.

The state stays spread: a rank holds its own agents' rows of the state, the running sums and the metrics' per-agent
arrays, and the channel's state of the arcs it draws, from the first step to the last (`Ranks`, the run loop's view of
the layout); memory per rank follows its own agents and ghosts. At checkpoints the ranks combine their agents' errors
(max for the worst agent, sums in the storage order for the consensus error, so that the numbers are a one-process
run's bit for bit) and each writes a shard of the checkpoint (`dgtd.run.checkpoint`); rank 0 gathers every agent's
iterates only where the output asks for them (a small run's trajectory, and the final results).

A rank that stops answering (killed, or its machine gone) would leave its neighbours waiting in the collective:
`Watchdog` ends a rank that has waited longer than ``timeout`` seconds with one line, and mpiexec then ends the job.
"""

from __future__ import annotations

import functools
import os
import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from dgtd.backends.mailbox import AGES, Mailbox
from dgtd.channels import Arcs
from dgtd.channels.base import copied, per_arc_fields
from dgtd.errors import DgtdInputError
from dgtd.graphs.topologies import unique_ints

MPI_ENV = ("PMI_SIZE", "OMPI_COMM_WORLD_SIZE", "PMIX_RANK")  # what mpiexec (MPICH's, Open MPI's) sets in its ranks
TIMEOUT = 300.0  # seconds a rank waits for its neighbours before it gives up (DGTD_MPI_TIMEOUT)
_WORLD: dict = {}
# Seconds this rank spent, summed over the run: in the step's exchange of messages (waiting for the others included),
# combining the metrics with the other ranks at checkpoints (`Ranks`: waiting included), gathering every agent's rows
# on rank 0 for the output, in its channel's draws and deliveries, and updating its own agents and ghosts
# (benchmarks/distributed.py reads them)
SECONDS = {"exchange": 0.0, "reduce": 0.0, "gather": 0.0, "draws": 0.0, "own": 0.0}


def launched() -> bool:
    """Whether this process is a rank of an mpiexec job (of any size, 1 included)."""
    return any(name in os.environ for name in MPI_ENV)


def world():
    """MPI's COMM_WORLD of this job (initialising MPI on first use), or None outside mpiexec."""
    if not launched():
        return None
    if "comm" not in _WORLD:
        try:
            from mpi4py import MPI
        except ImportError:
            raise DgtdInputError(
                "this is a rank of an mpiexec job but mpi4py is not installed: pip install 'dgtd[mpi]'"
            ) from None
        _WORLD["comm"] = MPI.COMM_WORLD
    return _WORLD["comm"]


def rank() -> int:
    comm = world()
    return 0 if comm is None else comm.Get_rank()


def size() -> int:
    comm = world()
    return 1 if comm is None else comm.Get_size()


def abort(code: int, line: str) -> None:
    """End every rank of the job at once (after Ctrl-C, which reaches the ranks inside Python only: one waiting in
    a collective for this one would wait on); what was checkpointed is intact, written atomically. ``line``: what
    rank 0 has said already, said by this rank if it is another (whose stderr is silenced), as it may be the only
    one that saw the interrupt."""
    if "comm" in _WORLD and _WORLD["comm"].Get_size() > 1:
        if _WORLD["comm"].Get_rank() != 0:
            os.write(2, (line + "\n").encode())
        _WORLD["comm"].Abort(code)


def on_this_machine() -> int:
    """How many ranks of the job share this rank's machine (its memory): MPI's shared-memory split, once (a
    collective: every rank asks, at the same point)."""
    if "here" not in _WORLD:
        from mpi4py import MPI

        node = world().Split_type(MPI.COMM_TYPE_SHARED)
        _WORLD["here"] = node.Get_size()
        node.Free()
    return _WORLD["here"]


def tightest_share(available: int | None) -> int | None:
    """The least memory free a rank over the job's machines (each machine's free memory over its ranks), the same on
    every rank (a collective), so that a run too large for one machine is refused by every rank at once; None where
    no rank knows its machine's."""
    from mpi4py import MPI

    mine = float("inf") if available is None else available / on_this_machine()
    least = world().allreduce(mine, op=MPI.MIN)
    return None if least == float("inf") else int(least)


def spread() -> bool:
    """Whether a run's agents are spread over more than one rank."""
    return size() > 1


def spreads(algorithm) -> bool:
    """Whether a run of ``algorithm`` spreads its agents over the ranks: under mpiexec with more than one rank, for
    every algorithm but a centralised learner (one estimate from every agent's samples: nothing to spread), which
    every rank runs whole, giving the numbers of one process."""
    return spread() and (bool(algorithm.messages) or algorithm.name == "local")


def check_supported(algorithm, channel, n_agents: int, backend: str, asynchronous: bool = False) -> None:
    """One line for what the runtime does not run (yet), the same on every rank."""
    if asynchronous and not launched():
        raise DgtdInputError(
            "--asynchronous is for agents spread over the ranks of an mpiexec job (mpiexec -n R dgtd run ...): "
            "one process has no rank to wait for; leave it out, or model late messages with --delay D"
        )
    if not spread():
        return
    R = size()
    if R > n_agents:
        raise DgtdInputError(f"{R} ranks for {n_agents} agents: run with at most {n_agents} ranks (mpiexec -n)")
    if backend == "jax":
        raise DgtdInputError(
            "ranks of an mpiexec job run --backend numba or numpy (the JAX backend runs one process, on its device)"
        )
    if asynchronous and backend != "numpy":
        raise DgtdInputError(
            "asynchronous ranks run the NumPy reference (their messages arrive between the steps of a kernel): "
            f"give --backend numpy with --asynchronous, not --backend {backend}"
        )
    if asynchronous and channel.holds:
        raise DgtdInputError(
            "late, asleep or compressed messages (--delay, --wake, --bits, --top-k) run across ranks synchronously, "
            "not with --asynchronous (whose messages are as late as the machine makes them): leave one out"
        )


@dataclass(frozen=True, eq=False)
class Partition:
    """Rank ``rank``'s share of the agents: ``own`` (a contiguous block of the storage order), ``local`` (own, then its
    ghosts: the other ranks' agents its own hear, in increasing order), the arcs into its own agents (``arcs``, in
    local numbering, each knowing its id, its agents' and its edge in the whole network (`dgtd.channels.Arcs`), in the
    global order, so that each agent's sums add in the order of a one-process run), ``edges`` (the ids of every edge
    whose draws this rank needs), and per neighbouring rank (``neighbours``) the local rows it sends (``send``) and
    receives into (``recv``).

    ``halo``, where an algorithm weighs what it hears by how much its neighbours heard (Metropolis weights), holds
    the arcs into the ghosts over rows of their own (the ghosts, then their neighbours; ``halo_ghosts``: the ghosts'
    rows there): the rank draws their events itself and counts what each ghost heard, without a message."""

    comm: Any  # the distributed-graph communicator of the linked ranks (mpi4py's Distgraphcomm)
    rank: int
    bounds: np.ndarray  # (R + 1,) rank r owns the agents order[bounds[r]] .. order[bounds[r + 1] - 1]
    order: np.ndarray  # the agents in storage order
    own: np.ndarray
    local: np.ndarray
    arcs: Arcs
    edges: np.ndarray
    neighbours: list
    send: list
    recv: list
    n_arcs: int = 0  # the whole network's
    halo: Arcs | None = None
    halo_ghosts: np.ndarray | None = None

    @property
    def arc_ids(self) -> np.ndarray:
        """The ids of the arcs into this rank's own agents, in the global order."""
        return self.arcs.arc_ids

    def drawn_arcs(self) -> tuple[np.ndarray, np.ndarray]:
        """(the ids of the arcs whose events this rank draws: into its own agents, then, for Metropolis weights, into
        its ghosts, as `heard` delivers them; which of them are its own to count and save)."""
        halo = [] if self.halo is None else [self.halo.arc_ids]
        ids = np.concatenate([self.arcs.arc_ids, *halo])
        return ids, np.arange(len(ids)) < self.arcs.n_arcs

    @classmethod
    def of(cls, arcs: Arcs, comm, order: np.ndarray | None = None, halo: bool = False) -> Partition:
        """Rank r's share: the agents order[bounds[r]:bounds[r + 1]] of the storage ``order`` (the compiled kernels'
        `dgtd.backends.compiled.graph.storage_order`: reverse Cuthill-McKee where it keeps more links local than
        the agents' own numbering; None: that numbering); with ``halo``, the arcs into its ghosts too."""
        R, r = comm.Get_size(), comm.Get_rank()
        N = arcs.n_agents
        order = np.arange(N) if order is None else order
        bounds = np.linspace(0, N, R + 1).astype(np.int64)
        owner = np.empty(N, np.int64)
        owner[order] = np.searchsorted(bounds, np.arange(N), side="right") - 1
        own = order[bounds[r] : bounds[r + 1]]
        into = np.flatnonzero(owner[arcs.dst] == r)  # arcs into my agents, in global order
        ghosts = unique_ints(arcs.src[into][owner[arcs.src[into]] != r])
        local = np.concatenate([own, ghosts])
        around = np.flatnonzero(np.isin(arcs.dst, ghosts)) if halo else np.zeros(0, np.int64)
        edges = unique_ints(np.concatenate([into, around]) // 2)
        sub = _share(arcs, local, into, edges)
        out_arcs = np.flatnonzero((owner[arcs.src] == r) & (owner[arcs.dst] != r))  # my agents heard elsewhere
        neighbours = sorted(set(owner[ghosts].tolist()) | set(owner[arcs.dst[out_arcs]].tolist()))
        row = np.full(N, -1, np.int64)
        row[local] = np.arange(len(local))
        send = [row[unique_ints(arcs.src[out_arcs][owner[arcs.dst[out_arcs]] == k])] for k in neighbours]
        recv = [row[ghosts[owner[ghosts] == k]] for k in neighbours]
        graph = comm.Create_dist_graph_adjacent(neighbours, neighbours, reorder=False)
        around_rows = halo_ghosts = None
        if halo:
            outer = np.setdiff1d(unique_ints(arcs.src[around]), ghosts, assume_unique=True)
            around_rows = _share(arcs, np.concatenate([ghosts, outer]), around, edges)
            halo_ghosts = np.arange(len(ghosts))
        return cls(
            graph,
            r,
            bounds,
            order,
            own,
            local,
            sub,
            edges,
            neighbours,
            send,
            recv,
            arcs.n_arcs,
            around_rows,
            halo_ghosts,
        )

    def exchange(self, sent: dict) -> None:
        """Each ghost row of the messages ``sent`` (name -> (B, local, q)) <- its owner's value, in place."""
        self.exchange_rows(list(sent.values()), self.send, self.recv)

    def exchange_rows(self, values: list, send: list, recv: list) -> None:
        """Rows ``recv[k]`` of every array of ``values`` (each (B, rows, q)) <- what neighbouring rank k sends from
        its rows ``send``, in place: `exchange` over this rank's local rows, or a compiled kernel's buffers over their
        storage rows (`compiled_block`)."""
        if not self.neighbours:
            return
        from mpi4py import MPI

        width = sum(x.shape[0] * x.shape[2] for x in values)  # numbers a row carries, every message side by side
        per = [width * len(rows) for rows in send]
        out = np.concatenate([x[:, rows].ravel() for rows in send for x in values]) if sum(per) else np.zeros(0)
        got = [width * len(rows) for rows in recv]
        into = np.empty(sum(got))
        self.comm.Neighbor_alltoallv(
            [out, per, np.concatenate([[0], np.cumsum(per)[:-1]]), MPI.DOUBLE],
            [into, got, np.concatenate([[0], np.cumsum(got)[:-1]]), MPI.DOUBLE],
        )
        at = 0
        for rows in recv:
            for x in values:
                n = x.shape[0] * len(rows) * x.shape[2]
                x[:, rows] = into[at : at + n].reshape(x.shape[0], len(rows), x.shape[2])
                at += n

    def counts(self, before, local):
        """``local`` (this rank's channel state after a block, its counts from zero) with the messages and bits every
        rank's agents heard in the block added to those of ``before`` (whole numbers: exact in any order)."""
        counts = world().allreduce(np.stack([local.messages, local.bits]))
        return local._replace(messages=before.messages + counts[0], bits=before.bits + counts[1])

    def gather(self, x: np.ndarray, axis: int = 1) -> np.ndarray | None:
        """Every rank's own rows of ``x`` (its own agents on ``axis``) in the agents' order, on rank 0 (None on the
        others): the whole network's array, where the output asks for it."""
        from mpi4py.util.dtlib import from_numpy_dtype

        mine = np.ascontiguousarray(np.moveaxis(x, axis, 0))  # agents first: the ranks' blocks line up
        rest = mine.shape[1:]
        width = int(np.prod(rest))
        N = int(self.bounds[-1])
        stored = np.empty((N, *rest), x.dtype) if self.rank == 0 else None
        counts = np.diff(self.bounds) * width
        displacements = self.bounds[:-1] * width
        kind = from_numpy_dtype(x.dtype)
        world().Gatherv(mine, [stored, counts, displacements, kind] if self.rank == 0 else None, root=0)
        if self.rank != 0:
            return None
        whole = np.empty_like(stored)
        whole[self.order] = stored
        return np.moveaxis(whole, 0, axis)


def _share(arcs: Arcs, rows: np.ndarray, ids: np.ndarray, edges: np.ndarray) -> Arcs:
    """The arcs ``ids`` of ``arcs`` (global ids, in order) over the agents ``rows`` (global ids), their links' up
    columns those of ``edges`` (sorted global edge ids)."""
    row = np.full(arcs.n_agents, -1, np.int64)
    row[rows] = np.arange(len(rows))
    return Arcs(len(rows), row[arcs.src[ids]], row[arcs.dst[ids]], ids, rows, np.searchsorted(edges, ids // 2))


def partition(ctx) -> Partition:
    """The run's `Partition` (built once per run and kept on its context)."""
    cache = ctx.__dict__.setdefault("_mpi", {})
    if "partition" not in cache:
        from dgtd.backends.compiled.graph import storage_order

        order = storage_order(ctx)
        halo = ctx.algorithm.mixing == "metropolis"
        cache["partition"] = Partition.of(ctx.arcs, world(), None if order is None else order[0], halo)
    return cache["partition"]


def kernel(ctx, backend: str, staleness):
    """The run's kernel on this rank: the compiled driver over its share (`compiled_block`) or the NumPy reference
    (`run_block`), synchronous, or asynchronous where ``staleness`` is not False (None: unbounded). A run the compiled
    backend does not run (`dgtd.backends.compiled.fallback`) takes the reference, with a one-line notice."""
    if backend != "numpy":
        from dgtd.backends.compiled import fallback

        if reason := fallback(ctx.algorithm, ctx.channel):
            import warnings

            warnings.warn(reason, stacklevel=3)
            backend = "numpy"
    ctx.__dict__.setdefault("_mpi", {})["compiled"] = backend != "numpy"
    if staleness is not False:
        return asynchronous(staleness)
    return compiled_block if backend != "numpy" else run_block


def share(ctx):
    """The run's compiled share (`dgtd.backends.share.Share`: this rank's rows, edges and channel as a run of its
    own), built once per run."""
    cache = ctx.__dict__.setdefault("_mpi", {})
    if "share" not in cache:
        from dgtd.backends.compiled.graph import storage_order
        from dgtd.backends.share import Share

        P = partition(ctx)
        order = storage_order(ctx)
        position = np.arange(ctx.network.n_nodes) if order is None else order[1]
        cache["share"] = Share.of(ctx, P.own, P.local[len(P.own) :], P.edges, position)
    return cache["share"]


def local_source(ctx, source):
    """``source`` drawing only this rank's numbers, where it can (a model's: `dgtd.sources.model.ModelSource.restrict`):
    the samples of its own agents and ghosts and the links of the edges it needs, O(N / R + boundary) a step. A source
    that cannot (a simulator's, a recording's) is read whole and its rows picked (`run_block`)."""
    if not hasattr(source, "restrict"):
        return source
    P = partition(ctx)
    compiled = ctx.__dict__["_mpi"].get("compiled")
    source.restrict(share(ctx).rows if compiled else P.local, P.edges)
    ctx.__dict__["_mpi"]["restricted"] = True
    return source


def local_sample(sample, local: np.ndarray):
    """The rows of a step's `Sample` of the agents ``local`` (a shared observation, one row, stays as it is)."""

    def rows(x):
        return x[:, local] if np.ndim(x) >= 2 and x.shape[1] > 1 else x

    return type(sample)(*(rows(x) for x in sample))


def _placed(x: np.ndarray, rows, n: int) -> np.ndarray:
    """``x`` (B, own, ...) in the rows ``rows`` of a (B, n, ...) array of zeros: a rank's own agents among its ghosts
    (whose values are never read: their messages come from their ranks at every step)."""
    out = np.zeros((x.shape[0], n, *x.shape[2:]), x.dtype)
    out[:, rows] = x
    return out


def _counting(state):
    """``state`` with its counts from zero: what a rank's agents hear in a block, which the ranks then add up."""
    B = state.messages.shape[0]
    return state._replace(messages=np.zeros(B), bits=np.zeros(B))


def channel_over(channel, whole: Arcs, ids: np.ndarray, seeds: int, seed: int):
    """``channel``'s state over the arcs ``ids`` of the network ``whole``, as the whole network's run begins it (each
    arc's draws keyed by its agents: `dgtd.streams.link_keys`)."""
    return channel.init(seeds, Arcs(whole.n_agents, whole.src[ids], whole.dst[ids], ids), seed)


def _split(state, n: int):
    """A channel state over the arcs [into own agents (n), into ghosts (the halo)] as the two, the first counting
    from zero."""
    fields = per_arc_fields(state)
    head = {name: x[:, :n] for name, x in fields.items()}
    tail = {name: x[:, n:] for name, x in fields.items()}
    return _counting(state._replace(**head)), state._replace(**tail)


def _joined(head, tail):
    """`_split`'s inverse: the per-arc fields side by side, the counts and the step of ``head``."""
    a, b = per_arc_fields(head), per_arc_fields(tail)  # (a side without arcs holds none: (B, 0))
    both = {
        name: np.concatenate([a[name], b[name]], axis=1) if name in a and name in b else a.get(name, b.get(name))
        for name in a | b
    }
    return head._replace(**both)


def heard(P: Partition, channel, mine, around, sent: dict, up, zeros: dict) -> tuple:
    """(what the own agents of this rank's share ``P`` heard: an `Inbox` over ``P.arcs``, the channel's state over
    those arcs, over the halo's) at one step, from ``sent`` (name -> (B, local rows, q), the ghosts' rows their owners'
    values) and the edges ``up`` this rank draws (``P.edges``). Where agents weigh what they hear by how much their
    neighbours heard (Metropolis weights: ``P.halo``), the ghosts' counts come from the draws of the arcs into them,
    whose values are not used (``zeros``, a dict the caller keeps from call to call)."""
    inbox, mine = channel.deliver(mine, P.arcs, sent, up)
    if P.halo is not None:
        for name, x in sent.items():  # (made once; again where a message's size changed: a shorter last round)
            if name not in zeros or zeros[name].shape[::2] != x.shape[::2]:
                zeros[name] = np.zeros((x.shape[0], P.halo.n_agents, x.shape[2]))
        heard_around, around = channel.deliver(around, P.halo, zeros, up)
        own = inbox.count()[:, : len(P.own)]
        inbox.degrees = np.concatenate([own, heard_around.count()[:, P.halo_ghosts]], axis=1)
    return inbox, mine, around


def run_block(ctx, state, channel_state, w_sum, alphas, blk, asynchronous: bool = False, staleness: int | None = None):
    """`dgtd.backends.reference.run_block`'s contract over this rank's own agents (``state``, ``w_sum``: their rows;
    ``channel_state``: the arcs it draws, `Ranks.arc_ids`). ``asynchronous``: the ghosts' messages are the newest
    received, waiting only for one at most ``staleness`` steps old (None: never; `dgtd.backends.mailbox`).

    The channel runs over the arcs into this rank's agents (and, for Metropolis weights, into its ghosts: ``halo``),
    each drawing the numbers the whole network's run draws for it; the block's samples are this rank's rows where the
    source draws them so (`local_source`), else the whole network's, of which it reads its own."""
    P = partition(ctx)
    algorithm, channel = ctx.algorithm, ctx.channel
    n = len(P.own)
    local = state._make(_placed(x, slice(0, n), len(P.local)) for x in state)
    sums = _placed(w_sum, slice(0, n), len(P.local))
    Phi, ratio, continuing = (ctx.Phi, ctx.ratio, ctx.continuing) if blk.table is None else blk.table
    restricted = ctx.__dict__["_mpi"].get("restricted", False)
    clock = time.perf_counter
    mail = None
    if asynchronous:
        ghosts = {name: np.array(x) for name, x in algorithm.sends(local).items()}
        P.exchange(ghosts)  # each ghost holds its owner's messages at the block start, until newer ones arrive
        mail = Mailbox(P, ghosts, len(alphas), staleness, WATCHDOG.beat)
    channel_state = copied(channel_state)  # (the channel updates its messages in flight in place)
    mine, around = _split(channel_state, P.arcs.n_arcs) if P.halo is not None else (_counting(channel_state), None)
    zeros: dict = {}  # the messages on the halo's arcs: their values are not used, made once a block
    for t in range(len(alphas)):
        t0 = clock()
        sums += algorithm.estimate(local)
        sent = {name: np.array(x) for name, x in algorithm.sends(local).items()}
        t1 = clock()
        if mail is None:
            P.exchange(sent)
        else:
            mail.swap(sent, t)
        WATCHDOG.beat()
        t2 = clock()
        up = None if blk.up is None else (blk.up[t] if restricted else blk.up[t][:, P.edges])
        inbox, mine, around = heard(P, channel, mine, around, sent, up, zeros)
        sample = blk.sample(t, Phi, ratio, ctx.gamma, continuing)
        sample = sample if restricted else local_sample(sample, P.local)
        t3 = clock()
        new = algorithm.update(local, sample, inbox, alphas[t])
        if inbox.awake is not None:  # an asleep agent keeps its state, as in `dgtd.backends.reference.run_block`
            new = new._make(np.where(inbox.awake[:, :, None], x, old) for x, old in zip(new, local))
        local = new
        t4 = clock()
        SECONDS["own"] += (t1 - t0) + (t4 - t3)
        SECONDS["exchange"] += t2 - t1
        SECONDS["draws"] += t3 - t2
    t5 = clock()
    if mail is not None:
        mail.finish()
    SECONDS["exchange"] += clock() - t5
    if len(alphas):
        channel_state = P.counts(channel_state, mine if around is None else _joined(mine, around))
    return state._make(np.ascontiguousarray(x[:, :n]) for x in local), channel_state, sums[:, :n].copy()


def compiled_block(ctx, state, channel_state, w_sum, alphas, blk):
    """`run_block` with the compiled driver (`dgtd.backends.compiled.driver.Advance`) over this rank's share
    (`dgtd.backends.share`): the share's samples drawn inside the kernel where the source is a model's, its ghosts'
    messages exchanged into the kernel's buffers between steps; the numbers of a one-process compiled run."""
    from dgtd.backends.compiled.driver import Advance
    from dgtd.samples import Draws

    P, S = partition(ctx), share(ctx)
    clock = time.perf_counter
    t0 = clock()
    own = S.local_rows[: len(P.own)]  # the share's rows of this rank's own agents
    local = state._make(_placed(x, own, len(S.rows)) for x in state)
    sums = _placed(w_sum, own, len(S.rows))
    restricted = ctx.__dict__["_mpi"].get("restricted", False)
    if not isinstance(blk, Draws) and not restricted:  # a simulator's or a recording's block: this share's rows
        blk = _rows_of_block(blk, S)
    run = Advance(S.ctx, local, _counting(channel_state), sums, alphas, blk)
    send = [run.storage_rows(S.local_rows[rows]) for rows in P.send]
    recv = [run.storage_rows(S.local_rows[rows]) for rows in P.recv]
    if len(alphas) == 0:
        run.advance(0)  # loads or compiles the kernels
    SECONDS["draws"] += clock() - t0
    for t in range(len(alphas)):
        t2 = clock()
        P.exchange_rows(list(run.message_rows()), send, recv)  # each message's (B, rows, q), a view of the buffer
        WATCHDOG.beat()
        t3 = clock()
        run.advance(t + 1)
        SECONDS["exchange"] += t3 - t2
        SECONDS["own"] += clock() - t3
    new, mine, sums = run.finish()
    channel = P.counts(channel_state, mine) if len(alphas) else channel_state
    return state._make(np.ascontiguousarray(x[:, own]) for x in new), channel, sums[:, own].copy()


compiled_block.draws_samples = True  # type: ignore[attr-defined]  # it takes `Draws` of a model's source


def _rows_of_block(blk, S):
    """A whole network's block cut to share ``S``: its rows' samples (a shared observation stays) and its edges."""
    from dgtd.samples import Block

    def rows(x):
        return x[:, :, S.rows] if x.shape[2] > 1 else x

    up = None if blk.up is None else np.ascontiguousarray(blk.up[:, :, S.edges])
    return Block(rows(blk.s), rows(blk.a), rows(blk.s_next), np.ascontiguousarray(blk.r[:, :, S.rows]), up, blk.table)


class Ranks:
    """The run loop's view of a run spread over the ranks (`dgtd.run.layout.Whole`'s for one process): which rows this
    rank holds (``agents``: its own, in storage order; ``arc_ids``: the arcs it draws, of which ``counted``, the arcs
    into its own agents, are its to report and save) and how the ranks combine what each holds: the worst agent by a
    max, the consensus error by sums up a fixed tree of the agents in storage order (`tree_sum`), so that every number
    is that of one process bit for bit; and every agent's rows on rank 0 where the output asks for them (`whole`)."""

    def __init__(self, ctx, kernel=None, asynchronous: bool = False):
        self.ctx, self.kernel, self.asynchronous = ctx, kernel, asynchronous
        self.partition = P = partition(ctx)
        self.agents, self.n_agents, self.root = P.own, int(P.bounds[-1]), P.rank == 0
        self.rank, self.n_ranks = P.rank, len(P.bounds) - 1
        if ctx.__dict__["_mpi"].get("compiled"):
            S = share(ctx)
            self.arc_ids, self.counted = S.arc_ids, S.counted.astype(bool)
        else:
            self.arc_ids, self.counted = P.drawn_arcs()

    @classmethod
    def of(cls, ctx, backend: str, asynchronous: bool, staleness: int | None, resume: dict | None = None) -> Ranks:
        """The layout of a run spread over the ranks, with its ``kernel`` (`kernel`: synchronous, or asynchronous
        with ``staleness``) and, for asynchronous ranks, the message ages counted from ``resume``'s (a collective)."""
        kernel_ = kernel(ctx, backend, staleness if asynchronous else False)
        if asynchronous:
            message_ages(restore=NO_AGES if resume is None else resume["message_ages"])
        return cls(ctx, kernel_, asynchronous)

    block_budget = 1 << 28  # a rank sets its share's driver up at each block: longer blocks (N / R agents a step)

    def local(self, source):
        """``source`` drawing only this rank's numbers, where it can (`local_source`)."""
        return local_source(self.ctx, source)

    def message_ages(self, restore: dict | None = None) -> dict:
        """The ages of the messages used, over the ranks (asynchronous ranks; a collective), else none."""
        return message_ages(restore) if self.asynchronous else {}

    def worst(self, x: np.ndarray) -> np.ndarray:
        """The worst agent's value (B,) of a per-agent quantity (B, own), over every rank."""
        return self.max(x.max(-1))

    def rows(self, x: np.ndarray) -> np.ndarray:
        """This rank's rows of a quantity of every agent (N, ...); one row for all (1, ...) stays."""
        return x[self.agents] if np.ndim(x) >= 2 and x.shape[0] == self.n_agents else x

    def max(self, x: np.ndarray) -> np.ndarray:
        from mpi4py import MPI

        x = np.ascontiguousarray(x)
        out = np.empty_like(x)
        self._timed(lambda: world().Allreduce(x, out, op=MPI.MAX), "reduce")
        return out

    def any(self, x: np.ndarray) -> np.ndarray:
        return self.max(x.astype(np.uint8)).astype(bool)

    def total(self, x: np.ndarray) -> np.ndarray:
        """Whole numbers (int64) summed over the ranks: exact, so in any order."""
        from mpi4py import MPI

        x = np.ascontiguousarray(x, dtype=np.int64)
        out = np.empty_like(x)
        self._timed(lambda: world().Allreduce(x, out, op=MPI.SUM), "reduce")
        return out

    def collect(self, x) -> list | None:
        """Every rank's ``x`` (a few numbers: pickled) in rank order on rank 0; None on the others."""
        return self._timed(lambda: world().gather(x, root=0), "gather")

    def tree_sum(self, x: np.ndarray) -> np.ndarray:
        """x (B, own, ...) summed over every rank's agents up the fixed tree of the agents in storage order
        (`dgtd.problems.exact.tree_pieces`): each rank's pieces (O(log N)) gathered by every rank as buffers (their
        counts, then their levels, indices and sums: no pickling, log R rounds each), combined the same way on every
        rank: one process's total bit for bit."""
        from dgtd.problems.exact import Pieces, tree_pieces, tree_total

        P = self.partition
        mine = tree_pieces(x, int(P.bounds[P.rank]))
        every = self._timed(lambda: Pieces(*(self._allgather(a) for a in mine)), "reduce")
        return tree_total(every, self.n_agents, x.shape[:1] + x.shape[2:])

    @staticmethod
    def _allgather(x: np.ndarray) -> np.ndarray:
        """Every rank's rows of ``x`` (any number a rank), concatenated in rank order on every rank."""
        from mpi4py.util.dtlib import from_numpy_dtype

        x = np.ascontiguousarray(x)
        width = int(np.prod(x.shape[1:]))
        counts = np.array(world().allgather(x.shape[0]), np.int64)
        out = np.empty((int(counts.sum()), *x.shape[1:]), x.dtype)
        displacements = np.r_[0, np.cumsum(counts)[:-1]] * width
        world().Allgatherv(x, [out, counts * width, displacements, from_numpy_dtype(x.dtype)])
        return out

    def consensus(self, W: np.ndarray) -> np.ndarray:
        """The consensus error (B,) of every agent's estimate, from this rank's rows W (B, own, q)."""
        from dgtd.problems.exact import ordered_consensus_error

        return ordered_consensus_error(W, self.n_agents, self.tree_sum)

    def init_channel(self, channel, seeds: int, seed: int):
        """The channel's state over the arcs this rank draws (`arc_ids`), as the whole network's run begins it."""
        return channel_over(channel, self.ctx.arcs, self.arc_ids, seeds, seed)

    def whole(self, x: np.ndarray, axis: int = 1) -> np.ndarray:
        """Every agent's rows of ``x`` (this rank's own on ``axis``) on rank 0; its own rows on the others."""
        whole = self._timed(lambda: self.partition.gather(x, axis), "gather")
        return whole if self.root else x

    def whole_arcs(self, x: np.ndarray, n_arcs: int) -> np.ndarray:
        """Every arc's entries (B, 2E) of a per-arc count ``x`` (B, arc_ids), each from its receiver's rank, on rank
        0; this rank's counted arcs on the others."""
        mine = self.reported(x)
        parts = self._timed(lambda: world().gather((self.arc_ids[self.counted], mine), root=0), "gather")
        if not self.root:
            return mine
        whole = np.zeros((x.shape[0], n_arcs))
        for ids, part in parts:
            whole[:, ids] = part
        return whole

    def reported(self, x: np.ndarray) -> np.ndarray:
        """The entries of the arcs into this rank's own agents of a per-arc array (B, arc_ids, ...)."""
        return x[:, self.counted]

    def shard(self) -> dict:
        """What a checkpoint's shard of this rank says it holds: its agents' and counted arcs' ids."""
        return {"agents": self.agents, "arcs": self.arc_ids[self.counted]}

    @staticmethod
    def _timed(compute, what: str):
        t = time.perf_counter()
        try:
            return compute()
        finally:
            SECONDS[what] += time.perf_counter() - t
            WATCHDOG.beat()


def asynchronous(staleness: int | None):
    """`run_block` with ranks that wait for each other's messages only when the newest is more than ``staleness``
    steps old (None: never)."""
    return functools.partial(run_block, asynchronous=True, staleness=staleness)


NO_AGES = {"counts": 0, "transit": 0.0}


def message_ages(restore: dict | None = None) -> dict:
    """The ages of the messages used and their seconds in transit, added up over the ranks (a collective: every rank
    calls it, at the same step): {"counts": ghosts used per age in steps (the last bin: that age and older),
    "transit": [messages received, their seconds in transit summed, the largest]}. ``restore``: start this run's
    counts from a checkpoint's (rank 0 holds them; the others start from zero)."""
    from mpi4py import MPI

    if restore is not None:
        AGES["counts"][:] = restore["counts"] if rank() == 0 else 0
        AGES["transit"][:] = restore["transit"] if rank() == 0 else 0.0
    counts = np.zeros_like(AGES["counts"])
    world().Allreduce(AGES["counts"], counts, op=MPI.SUM)
    received, seconds = world().allreduce(AGES["transit"][0], op=MPI.SUM), world().allreduce(AGES["transit"][1])
    largest = world().allreduce(AGES["transit"][2], op=MPI.MAX)
    return {"counts": counts, "transit": np.array([received, seconds, largest])}


class Watchdog:
    """Ends this rank with one line when a step has waited more than ``timeout`` seconds for its neighbours (a rank
    killed, or a machine gone): mpiexec then ends the others. Off until `start`."""

    def __init__(self):
        self.last, self.timeout, self.thread = time.monotonic(), TIMEOUT, None
        self.where = ""

    def beat(self) -> None:
        self.last = time.monotonic()

    def start(self, timeout: float, where: str) -> None:
        self.timeout, self.where, self.last = float(timeout), where, time.monotonic()
        if self.thread is None:
            self.thread = threading.Thread(target=self._watch, daemon=True, name="dgtd-mpi-watchdog")
            self.thread.start()

    def _watch(self) -> None:
        while True:
            time.sleep(min(1.0, self.timeout / 4))
            if time.monotonic() - self.last > self.timeout:
                line = (
                    f"dgtd: error: rank {rank()} waited more than {self.timeout:g} s for its neighbours (a rank may "
                    f"have died); what was checkpointed is intact: {self.where}\n"
                )
                os.write(2, line.encode())  # the process's own stderr (rank > 0 has sys.stderr silenced)
                os._exit(3)


WATCHDOG = Watchdog()


class LearnerRanks:
    """The agents of a learning run (`dgtd.run.learn`, `dgtd.run.networked`) spread over the ranks as a run's are, by
    the run's `Partition` (contiguous blocks in the agents' own numbering): each rank holds its agents' rows of every
    per-agent array (actors, critics, reward estimates) and steps them; they hear what is sent over the arcs into them
    (``arcs``: the rank's share, its rows its own agents then its ghosts), the ghosts' messages by the halo exchange
    and every link's draws the whole network's (`hear`), the channel's state over those arcs alone; what every agent
    needs of the others (the joint action on a shared state; at a checkpoint, every row on rank 0) is gathered in
    agent order. Every number is one process's, bit for bit. ``halo``: the agents weigh what they hear by their
    neighbours' counts (Metropolis weights), which the rank draws for its ghosts' arcs too. On a dense graph
    (`Arcs.dense`: a rank's ghosts are nearly every agent) every rank takes every agent's messages by one allgather
    and hears over the whole network's arcs, summing as one process does (`dgtd.run.learn.metropolis`'s dense mix)."""

    def __init__(self, n_agents: int, arcs: Arcs | None = None, halo: bool = False):
        comm = world()
        R = comm.Get_size()
        if R > n_agents:
            raise DgtdInputError(f"{R} ranks for {n_agents} agents: give at most one rank per agent")
        whole = Arcs.of(np.zeros((0, 2)), n_agents) if arcs is None else arcs
        self.partition = P = Partition.of(whole, comm, None, halo)
        self.comm, self.root, self.whole_arcs = comm, comm.Get_rank() == 0, whole
        self.local = P.own  # the agents held here (ids)
        self.dense = whole.dense
        if self.dense:  # every agent's rows and every arc, as in one process
            self.arcs, self.edges, self.own_rows = whole, np.arange(whole.n_arcs // 2), P.own
            self.arc_ids = np.arange(whole.n_arcs)
            self.counted = np.isin(whole.dst, P.own)
            return
        self.arcs, self.edges = P.arcs, P.edges  # the arcs into them over this rank's rows; the edges it draws
        self.own_rows = np.arange(len(P.own))  # the rows of the agents held here in what they hear
        self.arc_ids, self.counted = P.drawn_arcs()  # the arcs whose channel state this rank keeps; its own
        self.zeros: dict = {}  # the messages on the halo's arcs (values unused), made at the first round

    def init_channel(self, channel, seeds: int, seed: int):
        """The channel's state over the arcs this rank draws, as the whole network's run begins it."""
        return channel_over(channel, self.whole_arcs, self.arc_ids, seeds, seed)

    def hear(self, channel, links, sent: dict, up):
        """(an `Inbox` of what the agents held here heard, over ``arcs``; the channel's new state) from what they
        ``sent`` (name -> (B, n, q)) and the edges up (B, edges: this rank's, ``edges``); the counts of messages and
        bits those of every rank's agents."""
        P = self.partition
        if self.dense:
            return channel.deliver(links, self.arcs, {name: self.gather(x) for name, x in sent.items()}, up)
        rows = {name: _placed(x, slice(0, len(P.own)), len(P.local)) for name, x in sent.items()}
        P.exchange(rows)
        mine, around = _split(links, P.arcs.n_arcs) if P.halo is not None else (_counting(links), None)
        inbox, mine, around = heard(P, channel, mine, around, rows, up, self.zeros)
        return inbox, P.counts(links, mine if around is None else _joined(mine, around))

    reported = Ranks.reported

    def gather(self, x: np.ndarray) -> np.ndarray:
        """Every agent's rows (B, N, ...) of what each rank holds of them (B, n, ...), in agent order, on every rank."""
        return np.concatenate(self.comm.allgather(np.ascontiguousarray(x)), axis=1)

    def gather_root(self, x: np.ndarray) -> np.ndarray | None:
        """Every agent's rows (B, N, ...) on rank 0, which writes the results (None on the others): the checkpoints'
        exact measures are rank 0's alone."""
        parts = self.comm.gather(np.ascontiguousarray(x), root=0)
        return np.concatenate(parts, axis=1) if self.root else None

    def every(self, x: np.ndarray) -> np.ndarray:
        """``x`` (bools, the same shape on every rank) true on every rank."""
        return np.logical_and.reduce(self.comm.allgather(np.asarray(x, bool)))

    def shard(self) -> dict:
        """The ids of the agents and arcs whose rows this rank's checkpoint shard holds
        (`dgtd.run.checkpoint.assemble`)."""
        return {"agents": self.local, "arcs": self.arc_ids[self.counted]}
