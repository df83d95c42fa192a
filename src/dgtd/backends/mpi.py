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

At the end of every block the ranks gather the agents' state and running sums (one collective per block, thousands
of steps), so that every rank holds the whole run state there: the run loop's metrics, divergence checks and
checkpoints (`dgtd.run.loop.run`) are then those of a one-process run, and rank 0 writes them.

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
from dgtd.backends.share import PER_ARC, channel_share
from dgtd.channels import Arcs
from dgtd.errors import DgtdInputError

MPI_ENV = ("PMI_SIZE", "OMPI_COMM_WORLD_SIZE", "PMIX_RANK")  # what mpiexec (MPICH's, Open MPI's) sets in its ranks
TIMEOUT = 300.0  # seconds a rank waits for its neighbours before it gives up (DGTD_MPI_TIMEOUT)
_WORLD: dict = {}
# Seconds this rank spent, summed over the run's blocks: in the step's exchange of messages (waiting for the others
# included), in the gathers at block ends, in its channel's draws and deliveries, and updating its own agents and
# ghosts (benchmarks/distributed.py reads them)
SECONDS = {"exchange": 0.0, "gather": 0.0, "draws": 0.0, "own": 0.0}


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
    if asynchronous and backend != "numpy":
        raise DgtdInputError(
            "asynchronous ranks run the NumPy reference (their messages arrive between the steps of a kernel): "
            f"give --backend numpy with --asynchronous, not --backend {backend}"
        )
    if asynchronous and getattr(channel, "name", "perfect") not in ("perfect", "lossy"):
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
        ghosts = np.unique(arcs.src[into][owner[arcs.src[into]] != r])
        local = np.concatenate([own, ghosts])
        around = np.flatnonzero(np.isin(arcs.dst, ghosts)) if halo else np.zeros(0, np.int64)
        edges = np.unique(np.concatenate([into, around]) // 2)
        sub = _share(arcs, local, into, edges)
        out_arcs = np.flatnonzero((owner[arcs.src] == r) & (owner[arcs.dst] != r))  # my agents heard elsewhere
        neighbours = sorted(set(owner[ghosts].tolist()) | set(owner[arcs.dst[out_arcs]].tolist()))
        row = np.full(N, -1, np.int64)
        row[local] = np.arange(len(local))
        send = [row[np.unique(arcs.src[out_arcs][owner[arcs.dst[out_arcs]] == k])] for k in neighbours]
        recv = [row[ghosts[owner[ghosts] == k]] for k in neighbours]
        graph = comm.Create_dist_graph_adjacent(neighbours, neighbours, reorder=False)
        around_rows = halo_ghosts = None
        if halo:
            outer = np.setdiff1d(np.unique(arcs.src[around]), ghosts)
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

    def gather_channel(self, state, local, arc_ids=None, counted=None):
        """The whole network's channel state after a block: ``state`` (as it began) with every arc's fields from the
        rank of its receiver (``local``: this rank's share after the block, over the arcs into its agents, or over
        the arcs ``arc_ids`` of which it gives those ``counted``) and the counts of every rank added."""
        comm = world()
        whole = {}
        mine = None if arc_ids is None else counted.astype(bool)
        ids = self.arc_ids if arc_ids is None else arc_ids[mine]
        for name in PER_ARC:
            x = getattr(local, name)
            x = x if mine is None or not x.size else x[:, mine]
            if not x.size and not getattr(state, name).size:
                continue
            before = getattr(state, name)
            # made by the block where it began without them (the copies, at a run's first step): shaped from x
            whole[name] = before.copy() if before.size else np.zeros((x.shape[0], self.n_arcs) + x.shape[2:], x.dtype)
            for at, part in comm.allgather((ids, x)):
                whole[name][:, at] = part
        counts = comm.allreduce(np.stack([local.messages, local.bits]))  # whole numbers: exact in any order
        keep = {name: getattr(local, name) for name in ("keys", "step")}
        return state._replace(messages=state.messages + counts[0], bits=state.bits + counts[1], **keep, **whole)

    def gather(self, x: np.ndarray) -> np.ndarray:
        """Every rank's own rows of x (B, local, q) side by side: the whole (B, N, q), on every rank."""
        from mpi4py import MPI

        B, q = x.shape[0], x.shape[2]
        mine = np.ascontiguousarray(x[:, : len(self.own)].transpose(1, 0, 2))  # agents first: blocks line up
        counts = np.diff(self.bounds) * B * q
        stored = np.empty((int(self.bounds[-1]), B, q))  # in storage order
        world().Allgatherv(mine, [stored, counts, self.bounds[:-1] * B * q, MPI.DOUBLE])
        whole = np.empty((B, int(self.bounds[-1]), q))
        whole[:, self.order] = stored.transpose(1, 0, 2)
        return whole


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
    (`run_block`), synchronous, or asynchronous where ``staleness`` is not False (None: unbounded)."""
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
    rows = share(ctx).rows if compiled else P.local
    mine = share(ctx).local_rows if compiled else np.arange(len(P.local))  # own, then ghosts

    def gather(x):
        return P.gather(x[:, mine, None].astype(np.float64))[:, :, 0].astype(x.dtype)

    source.restrict(rows, P.edges, gather=gather)
    ctx.__dict__["_mpi"]["restricted"] = True
    return source


def local_sample(sample, local: np.ndarray):
    """The rows of a step's `Sample` of the agents ``local`` (a shared observation, one row, stays as it is)."""

    def rows(x):
        return x[:, local] if np.ndim(x) >= 2 and x.shape[1] > 1 else x

    return type(sample)(*(rows(x) for x in sample))


def run_block(ctx, state, channel_state, w_sum, alphas, blk, asynchronous: bool = False, staleness: int | None = None):
    """`dgtd.backends.reference.run_block`'s contract, this rank's agents only; returns the whole state, gathered.
    ``asynchronous``: the ghosts' messages are the newest received, waiting only for one at most ``staleness`` steps
    old (None: never; `dgtd.backends.mailbox`).

    The channel runs over the arcs into this rank's agents (and, for Metropolis weights, into its ghosts: ``halo``),
    each drawing the numbers the whole network's run draws for it; the block's samples are this rank's rows where the
    source draws them so (`local_source`), else the whole network's, of which it reads its own."""
    P = partition(ctx)
    algorithm, channel = ctx.algorithm, ctx.channel
    local = state._make(np.ascontiguousarray(x[:, P.local]) for x in state)
    sums = np.ascontiguousarray(w_sum[:, P.local])
    Phi, ratio, continuing = (ctx.Phi, ctx.ratio, ctx.continuing) if blk.table is None else blk.table
    restricted = ctx.__dict__["_mpi"].get("restricted", False)
    clock = time.perf_counter
    mail = Mailbox(P, algorithm.sends(local), len(alphas), staleness, WATCHDOG.beat) if asynchronous else None
    mine = channel_share(channel_state, P.arcs.arc_ids)
    halo = P.halo
    around = None if halo is None else channel_share(channel_state, halo.arc_ids)
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
        inbox, mine = channel.deliver(mine, P.arcs, sent, up)
        if halo is not None:  # what the ghosts heard, from the draws of the arcs into them (their values unused)
            zeros = zeros or {name: np.zeros((x.shape[0], halo.n_agents, x.shape[2])) for name, x in sent.items()}
            heard_around, around = channel.deliver(around, halo, zeros, up)
            own = inbox.count()[:, : len(P.own)]
            inbox.degrees = np.concatenate([own, heard_around.count()[:, P.halo_ghosts]], axis=1)
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
    t6 = clock()
    channel_state = P.gather_channel(channel_state, mine) if len(alphas) else channel_state
    new = state._make(P.gather(x) for x in local), channel_state, P.gather(sums)
    SECONDS["exchange"] += t6 - t5
    SECONDS["gather"] += clock() - t6
    return new


def compiled_block(ctx, state, channel_state, w_sum, alphas, blk):
    """`run_block` with the compiled driver (`dgtd.backends.compiled.driver.Advance`) over this rank's share
    (`dgtd.backends.share`): the share's samples drawn inside the kernel where the source is a model's, its ghosts'
    messages exchanged into the kernel's buffers between steps; the numbers of a one-process compiled run."""
    from dgtd.backends.compiled.driver import Advance
    from dgtd.samples import Draws

    P, S = partition(ctx), share(ctx)
    clock = time.perf_counter
    t0 = clock()
    local = state._make(np.ascontiguousarray(x[:, S.rows]) for x in state)
    sums = np.ascontiguousarray(w_sum[:, S.rows])
    restricted = ctx.__dict__["_mpi"].get("restricted", False)
    if not isinstance(blk, Draws) and not restricted:  # a simulator's or a recording's block: this share's rows
        blk = _rows_of_block(blk, S)
    run = Advance(S.ctx, local, S.channel_state(channel_state), sums, alphas, blk)
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
    t4 = clock()
    new, mine, sums = run.finish()
    mine_rows = S.local_rows  # own then ghosts: the rows `Partition.gather` reads its own from
    whole = state._make(P.gather(x[:, mine_rows]) for x in new)
    channel = P.gather_channel(channel_state, mine, S.arc_ids, S.counted)
    SECONDS["gather"] += clock() - t4
    return whole, channel, P.gather(sums[:, mine_rows])


compiled_block.draws_samples = True  # type: ignore[attr-defined]  # it takes `Draws` of a model's source


def _rows_of_block(blk, S):
    """A whole network's block cut to share ``S``: its rows' samples (a shared observation stays) and its edges."""
    from dgtd.samples import Block

    def rows(x):
        return x[:, :, S.rows] if x.shape[2] > 1 else x

    up = None if blk.up is None else np.ascontiguousarray(blk.up[:, :, S.edges])
    return Block(rows(blk.s), rows(blk.a), rows(blk.s_next), np.ascontiguousarray(blk.r[:, :, S.rows]), up, blk.table)


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
