"""The agents of a run spread over the ranks of an MPI job (``mpiexec -n R dgtd run ...``): synchronously, or with
``--asynchronous`` ranks that do not wait for each other's messages (`dgtd.backends.mailbox`; then the exchange below
is its non-blocking messages).

Rank r holds a contiguous block of the agents in their storage order (`Partition`: the compiled kernels' order,
reverse Cuthill-McKee where it keeps more links local, split as evenly as it goes) and updates only
those, with the NumPy reference's arithmetic (`dgtd.backends.reference`), so that a run on R ranks gives the numbers
of a one-process ``--backend numpy`` run bit for bit. At every step each rank sends the messages of its agents that
another rank's agents hear (the links that cross ranks) and receives those of its ghosts (the other ranks' agents its
own hear), through one neighbourhood collective on a distributed-graph communicator of the ranks whose agents are
linked; links inside a rank cost nothing. The samples and the channel's draws (edges up, losses) are drawn on every
rank from the seed's own streams (each rank draws what every rank draws, a cost of O(N + |E|) numbers a step), which
is what keeps a seed's numbers independent of the number of ranks; each rank then reads its own agents' rows.

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
from dgtd.channels import Arcs, Inbox
from dgtd.errors import DgtdInputError

MPI_ENV = ("PMI_SIZE", "OMPI_COMM_WORLD_SIZE", "PMIX_RANK")  # what mpiexec (MPICH's, Open MPI's) sets in its ranks
TIMEOUT = 300.0  # seconds a rank waits for its neighbours before it gives up (DGTD_MPI_TIMEOUT)
_WORLD: dict = {}
# Seconds this rank spent, summed over the run's blocks: in the step's exchange of messages (waiting for the others
# included), in the gathers at block ends, drawing what every rank draws (samples and the channel's events), and
# updating its own agents (benchmarks/distributed.py reads them)
SECONDS = {"exchange": 0.0, "gather": 0.0, "replicated": 0.0, "own": 0.0}


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
    if backend != "numpy":
        raise DgtdInputError(
            "under mpiexec every rank runs the NumPy reference arithmetic (the numbers of --backend numpy, bit for "
            f"bit): leave out --backend {backend} or give --backend numpy"
        )
    if asynchronous and getattr(channel, "name", "perfect") not in ("perfect", "lossy"):
        raise DgtdInputError(
            "late, asleep or compressed messages (--delay, --wake, --bits, --top-k) run across ranks synchronously, "
            "not with --asynchronous (whose messages are as late as the machine makes them): leave one out"
        )


@dataclass(frozen=True, eq=False)
class Partition:
    """Rank ``rank``'s share of the agents: ``own`` (a contiguous range of agent ids), ``local`` (own, then its
    ghosts: the other ranks' agents its own hear, in increasing order), the arcs into its own agents (``arcs``, in
    local numbering; ``arc_ids``, their global ids, in the global order, so that each agent's sums add in the order
    of a one-process run), and per neighbouring rank (``neighbours``) the local rows it sends (``send``) and
    receives into (``recv``)."""

    comm: Any  # the distributed-graph communicator of the linked ranks (mpi4py's Distgraphcomm)
    rank: int
    bounds: np.ndarray  # (R + 1,) rank r owns the agents order[bounds[r]] .. order[bounds[r + 1] - 1]
    order: np.ndarray  # the agents in storage order
    own: np.ndarray
    local: np.ndarray
    arcs: Arcs
    arc_ids: np.ndarray
    neighbours: list
    send: list
    recv: list

    @classmethod
    def of(cls, arcs: Arcs, comm, order: np.ndarray | None = None) -> Partition:
        """Rank r's share: the agents order[bounds[r]:bounds[r + 1]] of the storage ``order`` (the compiled kernels'
        `dgtd.backends.compiled.graph.storage_order`: reverse Cuthill-McKee where it keeps more links local than
        the agents' own numbering; None: that numbering)."""
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
        row = np.full(N, -1, np.int64)
        row[local] = np.arange(len(local))
        sub = Arcs(len(local), row[arcs.src[into]], row[arcs.dst[into]])
        out_arcs = np.flatnonzero((owner[arcs.src] == r) & (owner[arcs.dst] != r))  # my agents heard elsewhere
        neighbours = sorted(set(owner[ghosts].tolist()) | set(owner[arcs.dst[out_arcs]].tolist()))
        send = [row[np.unique(arcs.src[out_arcs][owner[arcs.dst[out_arcs]] == k])] for k in neighbours]
        recv = [row[ghosts[owner[ghosts] == k]] for k in neighbours]
        graph = comm.Create_dist_graph_adjacent(neighbours, neighbours, reorder=False)
        return cls(graph, r, bounds, order, own, local, sub, into, neighbours, send, recv)

    def exchange(self, sent: dict) -> None:
        """Each ghost row of the messages ``sent`` (name -> (B, local, q)) <- its owner's value, in place."""
        if not self.neighbours:
            return
        from mpi4py import MPI

        values = list(sent.values())
        per = [sum(x.shape[0] * x.shape[2] for x in values) * len(rows) for rows in self.send]
        out = np.concatenate([x[:, rows].ravel() for rows in self.send for x in values]) if sum(per) else np.zeros(0)
        got = [sum(x.shape[0] * x.shape[2] for x in values) * len(rows) for rows in self.recv]
        into = np.empty(sum(got))
        self.comm.Neighbor_alltoallv(
            [out, per, np.concatenate([[0], np.cumsum(per)[:-1]]), MPI.DOUBLE],
            [into, got, np.concatenate([[0], np.cumsum(got)[:-1]]), MPI.DOUBLE],
        )
        at = 0
        for rows in self.recv:
            for x in values:
                n = x.shape[0] * len(rows) * x.shape[2]
                x[:, rows] = into[at : at + n].reshape(x.shape[0], len(rows), x.shape[2])
                at += n

    def gather_arcs(self, channel_state):
        """The copies' channel's state (`dgtd.channels.ChannelState`) with each arc's copies and messages in flight
        from the rank of its receiver, on every rank (the rest of it is drawn alike on every rank)."""
        whole = {}
        for name in ("copies", "pending"):
            x = getattr(channel_state, name)
            whole[name] = np.empty_like(x)
            for ids, part in world().allgather((self.arc_ids, x[:, self.arc_ids])):
                whole[name][:, ids] = part
        return channel_state._replace(**whole)

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


def everyone(sent: dict, P: Partition, n_agents: int) -> dict:
    """The messages ``sent`` (name -> (B, local, q)) in every agent's row (B, N, q): this rank's own agents' and
    ghosts' where they are, zeros elsewhere."""
    out = {}
    for name, x in sent.items():
        out[name] = np.zeros((x.shape[0], n_agents, x.shape[2]))
        out[name][:, P.local] = x
    return out


def partition(ctx) -> Partition:
    """The run's `Partition` (built once per run and kept on its context)."""
    cache = ctx.__dict__.setdefault("_mpi", {})
    if "partition" not in cache:
        from dgtd.backends.compiled.graph import storage_order

        order = storage_order(ctx)
        cache["partition"] = Partition.of(ctx.arcs, world(), None if order is None else order[0])
    return cache["partition"]


def local_sample(sample, local: np.ndarray):
    """The rows of a step's `Sample` of the agents ``local`` (a shared observation, one row, stays as it is)."""

    def rows(x):
        return x[:, local] if np.ndim(x) >= 2 and x.shape[1] > 1 else x

    return type(sample)(*(rows(x) for x in sample))


def run_block(ctx, state, channel_state, w_sum, alphas, blk, asynchronous: bool = False, staleness: int | None = None):
    """`dgtd.backends.reference.run_block`'s contract, this rank's agents only; returns the whole state, gathered.
    ``asynchronous``: the ghosts' messages are the newest received, waiting only for one at most ``staleness`` steps
    old (None: never; `dgtd.backends.mailbox`)."""
    P = partition(ctx)
    algorithm, channel = ctx.algorithm, ctx.channel
    local = state._make(np.ascontiguousarray(x[:, P.local]) for x in state)
    sums = np.ascontiguousarray(w_sum[:, P.local])
    Phi, ratio, continuing = (ctx.Phi, ctx.ratio, ctx.continuing) if blk.table is None else blk.table
    metropolis = algorithm.mixing == "metropolis"
    clock = time.perf_counter
    mail = Mailbox(P, algorithm.sends(local), len(alphas), staleness, WATCHDOG.beat) if asynchronous else None
    copies = channel.name == "imperfect"
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
        up = None if blk.up is None else blk.up[t]
        # every arc's draws, on every rank; the copies' channel holds what arcs carry, right here for those into
        # this rank's agents (their senders are its own agents and ghosts; the other rows are zeros)
        given = everyone(sent, P, ctx.arcs.n_agents) if copies else sent
        whole, channel_state = channel.deliver(channel_state, ctx.arcs, given, up)
        degrees = ctx.arcs.into(whole.heard[:, :, None])[:, P.local, 0] if metropolis else None
        weights = None if whole.weights is None else whole.weights[P.arc_ids]
        received = {name: x[:, P.arc_ids] for name, x in whole.received.items()}
        awake = None if whole.awake is None else whole.awake[:, P.local]
        inbox = Inbox(P.arcs, sent, whole.heard[:, P.arc_ids], received, weights, awake, degrees)
        sample = local_sample(blk.sample(t, Phi, ratio, ctx.gamma, continuing), P.local)
        t3 = clock()
        new = algorithm.update(local, sample, inbox, alphas[t])
        if awake is not None:  # an asleep agent keeps its state, as in `dgtd.backends.reference.run_block`
            new = new._make(np.where(awake[:, :, None], x, old) for x, old in zip(new, local))
        local = new
        t4 = clock()
        SECONDS["own"] += (t1 - t0) + (t4 - t3)
        SECONDS["exchange"] += t2 - t1
        SECONDS["replicated"] += t3 - t2
    t5 = clock()
    if mail is not None:
        mail.finish()
    t6 = clock()
    if copies and len(alphas):
        channel_state = P.gather_arcs(channel_state)
    new = state._make(P.gather(x) for x in local), channel_state, P.gather(sums)
    SECONDS["exchange"] += t6 - t5
    SECONDS["gather"] += clock() - t6
    return new


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
