"""The compiled driver: one for every algorithm. It owns what is not an algorithm's maths, once:

- the layouts: seeds one after another, or several at once in threads (`_seeds`), or the agents of a seed spread over
  the cores at every step (`_agents`), chosen per run and, where both fit, by measuring which is faster here now
  (`Layouts`): on a machine shared with another busy process the agent layout's per-step synchronisation collapses;
- the samples, drawn inside the kernel from the seeds' keyed streams (`dgtd.backends.compiled.sampling`: the samples
  of the NumPy reference) or copied from a block of a simulator's or a recording's;
- the messages, double-buffered: every agent reads its neighbours' values of step k while it writes its own of step
  k + 1 (the Jacobi form of every algorithm here), and the channel (`dgtd.backends.compiled.channel`): the neighbours
  heard, their aggregates, the counts;
- the graph's neighbour lists in the storage order of the agents (`dgtd.backends.compiled.graph`), dense, sparse and
  table-supplied features, and episodic discounts (`dgtd.backends.compiled.step`).

An algorithm's compiled part is its per-agent step (`dgtd.backends.compiled.step`), which the driver calls for every
learner at every step: the compiled contract is `dgtd.backends.reference.run_block`'s, the same samples and the same
arithmetic, so that the two agree to rounding (tested for every algorithm). The serial loop and the parallel agent
layout are compiled only when a run uses them, each once per algorithm, and cached on disk.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import numpy as np
from numba import get_num_threads, njit, prange

from dgtd.backends.compiled.cache import load_quickly
from dgtd.backends.compiled.channel import Inbox, count_heard, hear, metropolis_weights
from dgtd.backends.compiled.graph import graph_arrays, per_run, storage_graph, storage_order
from dgtd.backends.compiled.held import carry
from dgtd.backends.compiled.sampling import (
    Sampler,
    _sample_step,
    _step_edges,
    _step_observations,
    channel_draws,
    entity_ids,
    link_keys_of,
    sample_args,
)
from dgtd.backends.compiled.step import CompiledStep, Features, Samples, step_of
from dgtd.channels import counted
from dgtd.samples import Block, Draws, SampleTable

# The kernels below are templates: `driver` compiles a copy of each per algorithm, with the algorithm's step in
# place of `agent_step` and its flag in place of NEEDS_DEGREES, under the numba options it names.


def agent_step(p, own, sums, inbox, out, work, x, feat, b, i, agent, alpha, q):
    """Stands for an algorithm's compiled step (`dgtd.backends.compiled.step.compiled_step`)."""
    raise NotImplementedError("the driver's kernels run as compiled by `driver`")


NEEDS_DEGREES = False  # whether the step's inbox needs every agent's count of messages heard


def _learner(p, own, sums, inbox, out, work, x, feat, graph, up, up_row, b, i, alpha, q):
    """Learner i of seed b at one step: the neighbours it heard, then its step."""
    indptr, nbr, eid, agent_of, arc_weights = graph
    if inbox.sent.shape[0] > 0:
        hear(inbox, up, up_row, indptr, nbr, eid, i)
        if NEEDS_DEGREES:
            metropolis_weights(inbox, i)
    agent_step(p, own, sums, inbox, out, work, x, feat, b, i, agent_of[i], alpha, q)


def _seeds(p, own, sums, buffers, first, alphas, sampler, feat, x, graph, space, b0, b1):
    """Seeds b0 .. b1 - 1 one after another, each its steps in order, each step its learners in order. No threads of
    its own (it releases the GIL: `Layouts` runs several calls at once over separate seeds, each with its own
    ``space``, `_space`, and samples ``x`` in its rows)."""
    L, T, q = sums.shape[1], alphas.shape[0], sums.shape[2]
    for b in range(b0, b1):
        arcs_up = 0  # summed here, stored once: seeds next to each other share a cache line of n_up
        for t in range(T):
            arcs_up += _sample_step(sampler, b, 0, t, space)
            if NEEDS_DEGREES:
                count_heard(space.up, 0, graph.indptr, graph.eid, space.degree, 0)
            sent, out = buffers[(first + t) % 2], buffers[(first + t + 1) % 2]  # read one buffer, write the other
            inbox = Inbox(
                sent, space.heard, space.n_heard, space.weights, space.degree, 0, space.scratch, 0, graph.arc_weights
            )
            for i in range(L):
                _learner(p, own, sums, inbox, out, space.work, x, feat, graph, space.up, 0, b, i, alphas[t], q)
        sampler.n_up[b] += arcs_up


def _seeds_held(p, own, sums, buffers, first, alphas, sampler, feat, x, graph, space, links, held, b0, b1):
    """`_seeds` over a channel whose receivers hold copies (`dgtd.backends.compiled.held`; ``space`` a `HeldSpace`):
    at each step the channel first carries the messages (`carry`), then each awake learner steps, reading its
    neighbours' copies in rows N + a; an asleep one keeps its state and reports its estimate (message 0, w, for every
    algorithm that sends)."""
    L, T, M, q = sums.shape[1], alphas.shape[0], buffers.shape[1], sums.shape[2]
    N = space.r.shape[1]
    degree, up_t, awake = space.degree, space.up, space.awake
    for b in range(b0, b1):
        for t in range(T):
            sampler.n_up[b] += _sample_step(sampler, b, 0, t, space)
            sent, out = buffers[(first + t) % 2], buffers[(first + t + 1) % 2]
            step = held.step[b] + t
            scratch = (awake, space.late, space.rounding, space.value, space.chosen)
            held.delivered[b] += carry(links, held, b, step, sampler.rng, up_t, sent, N, scratch)
            if NEEDS_DEGREES:
                count_heard(up_t, 0, graph.indptr, graph.eid, degree, 0)
                for a in range(links.src_row.shape[0]):  # a copy's row counts as its sender
                    degree[0, N + a] = degree[0, links.src_row[a]]
            inbox = Inbox(
                sent, space.heard, space.n_heard, space.weights, degree, 0, space.scratch, 0, graph.arc_weights
            )
            for i in range(L):
                if awake[graph.agent_of[i]]:
                    _learner(p, own, sums, inbox, out, space.work, x, feat, graph, up_t, 0, b, i, alphas[t], q)
                else:
                    for f in range(q):
                        sums[b, i, f] += sent[0, b, i, f]
                    for m in range(M):
                        for f in range(q):
                            out[m, b, i, f] = sent[m, b, i, f]
        held.step[b] += T


def _chunk(c, n_chunks, t, p, own, sums, buffers, first, alphas, sampler, feat, x, graph, space):
    """Chunk c of the agent layout at step t: its share of the B * N (seed, agent) pairs, then its share of the
    sampling of step t + 1 (`_agents`)."""
    B, L, T, q = sums.shape[0], sums.shape[1], alphas.shape[0], sums.shape[2]
    sent, out = buffers[(first + t) % 2], buffers[(first + t + 1) % 2]
    now, nxt = (t % 2) * B, ((t + 1) % 2) * B  # rows of this step's samples and the next step's
    total = B * L
    for flat in range(c * total // n_chunks, (c + 1) * total // n_chunks):
        b, i = flat // L, flat % L
        inbox = Inbox(
            sent, space.heard, space.n_heard, space.weights, space.degree, now + b, space.scratch, c, graph.arc_weights
        )
        at = Samples(x.s, x.a, x.s_next, x.r, now + b, x.ratio, x.continuing, x.gamma)
        _learner(p, own, sums, inbox, out, space.work, at, feat, graph, space.up, now + b, b, i, alphas[t], q)
    if t + 1 < T:  # the samples of step t + 1: every chunk draws its share of each seed's observations (the numbers
        # are keyed: any part can be drawn anywhere), and seed j's edges fall to chunk n_chunks - 1 - j % n_chunks
        n_obs = space.s.shape[1]
        o0, o1 = c * n_obs // n_chunks, (c + 1) * n_obs // n_chunks
        for sb in range(B):
            _step_observations(sampler, sb, nxt + sb, t + 1, space.s, space.a, space.s_next, space.r, o0, o1)
            if c == n_chunks - 1 - sb % n_chunks:
                sampler.n_up[sb] += _step_edges(sampler, sb, nxt + sb, t + 1, space.up)
                if NEEDS_DEGREES:
                    count_heard(space.up, nxt + sb, graph.indptr, graph.eid, space.degree, nxt + sb)


def _agents(p, own, sums, buffers, first, alphas, sampler, feat, x, graph, space, n_chunks):
    """The agents of every seed spread over the cores at every step, in ``n_chunks`` chunks (`_chunk`, compiled on its
    own: the parallel part stays small and compiles in a moment). Samples are double-buffered too: while the agents
    update with step k's, the chunks also draw step k + 1's, each chunk its share of every seed's observations and
    rewards and one chunk a seed's edges (each number is keyed by what it is for, so any part can be drawn anywhere
    and in any order), so that no core waits while another samples. numba hands a parallel loop flat records (of
    arrays and numbers) only: every argument here is one."""
    B, T = sums.shape[0], alphas.shape[0]
    for b in range(B if T > 0 else 0):  # step 0's samples
        sampler.n_up[b] += _sample_step(sampler, b, b, 0, space)
        if NEEDS_DEGREES:
            count_heard(space.up, b, graph.indptr, graph.eid, space.degree, b)
    for t in range(T):
        for c in prange(n_chunks):
            _chunk(c, n_chunks, t, p, own, sums, buffers, first, alphas, sampler, feat, x, graph, space)


def driver(compiled: CompiledStep) -> tuple:
    """(`_seeds`, `_agents`) compiled for an algorithm's step: copies of the templates above with its step in place of
    `agent_step`, each compiled on first use and cached on disk under a name of its own (`_seeds_dgtd`, ...).

    The step is then an ordinary global of the copies, which numba inlines as it inlines every helper here; chosen at
    compile time through an overload instead, it was inlined wrongly (numba 0.68: array stores after it were lost).
    The serial loop and a chunk of the agent layout run without numba's reference counts (``_nrt=False``): every
    array comes in from Python, none is made there, and an array taken out of a tuple would otherwise cost an atomic
    increment and decrement at every agent-step (measured: half the time of a step)."""
    if compiled.key not in _DRIVERS:
        _DRIVERS[compiled.key] = _copies(compiled)
    return _DRIVERS[compiled.key]


_DRIVERS: dict = {}


def _copies(compiled: CompiledStep) -> tuple:
    space, suffix, cache = _template_space(compiled), compiled.key, compiled.cache
    compiled_copy(_learner, space, suffix, inline="always")
    seeds = compiled_copy(_seeds, space, suffix, cache, nogil=True, _nrt=False)
    chunk = compiled_copy(_chunk, space, suffix, cache, nogil=True, _nrt=False)
    agents = compiled_copy(_agents, space, suffix, cache, parallel=True)
    load_quickly(seeds, chunk, agents)
    return seeds, agents


def _template_space(compiled: CompiledStep) -> dict:
    """The globals the templates' copies see: this module's, with the algorithm's step and flag in place."""
    return dict(globals(), agent_step=compiled.step, NEEDS_DEGREES=compiled.degrees)


def compiled_copy(fn, space: dict, suffix: str, cache: bool = True, **options):
    """Template ``fn`` compiled in ``space`` under the name ``{fn.__name__}_{suffix}`` (its disk cache's name), and
    put there under its own name for the copies that call it."""
    import types

    clone = types.FunctionType(fn.__code__, space, f"{fn.__name__}_{suffix}", fn.__defaults__, fn.__closure__)
    clone.__qualname__, clone.__doc__ = clone.__name__, fn.__doc__
    space[fn.__name__] = dispatcher = njit(cache=cache, **options)(clone)
    return dispatcher


# --- The Python side: arrays in, layout chosen, arrays out ----------------------------------------------------------

AGENTS_MIN_WORK = 1 << 14  # N q from which spreading a seed's agents over the cores can pay (measured: N = 256, q = 64)
LAYOUT = "auto"  # "seeds" or "agents" force a layout (the tests run both); "auto" chooses (`Layouts`)
_POOL: list = []  # the threads that run seeds side by side
GROUPS_PER_THREAD = 4  # groups of seeds per thread: a thread slowed by another process takes fewer
THREADED_WORK = 50_000  # agent-steps from which a block's seeds run in threads (a few ms; less pays no hand-over)
JOB_WORK = 200_000  # agent-steps a group of seeds holds at least, where there are enough (a call costs a fraction
# of a millisecond: measured, 4 seeds of 5 agents in 4 groups per block ran at 0.75 the rate of 2 groups)


def run_block(ctx, state, channel, w_sum: np.ndarray, alphas: np.ndarray, blk):
    """The contract of `dgtd.backends.reference.run_block`, compiled; ``blk`` is a `Block` of samples or `Draws`
    that the kernel draws itself (the same samples, never materialised)."""
    run = Advance(ctx, state, channel, w_sum, alphas, blk)
    run.advance(alphas.shape[0])
    return run.finish()


class Advance:
    """A block set up for the compiled kernels (the state in storage rows, the message buffers, the sampling
    arguments), advanced a number of steps at a time (`advance`: an MPI rank exchanges its ghosts' messages between
    steps, `message_rows`), and handed back (`finish`)."""

    def __init__(self, ctx, state, channel, w_sum: np.ndarray, alphas: np.ndarray, blk):
        algorithm = self.algorithm = ctx.algorithm
        compiled = step_of(algorithm)
        if compiled is None:
            raise TypeError(f"{algorithm.name} writes update alone: the compiled driver cannot run it")
        self.compiled = compiled
        messages = self.messages = tuple(algorithm.messages)
        B, L, q = w_sum.shape
        N = self.N = ctx.network.n_nodes
        self.holds = bool(messages) and ctx.channel.holds
        A = ctx.arcs.n_arcs if self.holds else 0  # rows N + a of the buffers hold arc a's copies (`_seeds_held`)
        order = self.order = storage_order(ctx) if messages else None  # agents in rows near their neighbours
        rows = (lambda x: x) if order is None else (lambda x: x[:, order[0]])
        copy = lambda x: np.array(rows(x), dtype=np.float64, order="C")  # noqa: E731  (updated in place)
        self.own_names = [f for f in state._fields if f not in messages]
        if tuple(self.own_names) != compiled.own:
            raise TypeError(f"{algorithm.name}'s compiled step keeps {compiled.own}, its state {tuple(self.own_names)}")
        own = np.stack([copy(getattr(state, f)) for f in self.own_names]) if self.own_names else np.zeros((0, B, L, q))
        sent = algorithm.sends(state)
        # step k's messages in buffers[k % 2], k counted in the block
        self.buffers = np.zeros((2, len(messages), B, N + A, q))
        for m, name in enumerate(messages):
            self.buffers[0, m, :, :N] = rows(sent[name])
        sums = copy(w_sum)
        self.sampler = sample_args(ctx, blk, B, channel)
        Phi, ratio = rows_of(ctx, blk)
        self.args = Args(
            algorithm.params(),
            own,
            sums,
            self.sampler,
            Features(*feature_arrays(ctx, blk)),
            readonly(ratio),
            continuing_flags(ctx, blk),
            float(ctx.gamma),
            _graph(ctx, bool(messages)),
        )
        self.ctx, self.state, self.channel, self.blk = ctx, state, channel, blk
        self.alphas = np.ascontiguousarray(alphas)
        self.newest, self.t = 0, 0  # the buffer of the newest messages, and the steps taken

    def message_rows(self) -> np.ndarray:
        """(messages, B, N, q): the newest messages in the agents' own rows order (a view: an MPI rank writes its
        ghosts' rows there between steps, through `storage_rows`)."""
        return self.buffers[self.newest][:, :, : self.N]

    def storage_rows(self, rows: np.ndarray) -> np.ndarray:
        """Where agents ``rows`` sit in the buffers."""
        return rows if self.order is None else self.order[1][rows]

    def advance(self, t1: int) -> None:
        """Steps self.t .. t1 - 1 of the block (none: load or compile the kernels it runs)."""
        ctx, compiled = self.ctx, self.compiled
        if self.holds:
            self.newest, self.channel = _run_held(
                ctx, compiled, self.args, self.buffers, self.alphas, self.blk, self.channel, self.t, t1, self.newest
            )
        else:
            B, L, q = self.args.sums.shape
            self.newest = _layouts(ctx, B, L, q, bool(self.messages)).run(
                driver(compiled),
                self.args,
                self.buffers,
                self.alphas,
                self.blk,
                len(self.messages),
                compiled.work,
                self.t,
                t1,
                self.newest,
            )
        self.t = t1

    def finish(self):
        """(the new state, the channel's, the running sums) in the agents' own order, the sources settled."""
        sampler, channel, state, q = self.sampler, self.channel, self.state, self.args.sums.shape[2]
        T, order, messages = self.t, self.order, self.messages
        back = (lambda x: x) if order is None else (lambda x: np.ascontiguousarray(x[:, order[1]]))
        if isinstance(self.blk, Draws):
            self.blk.settle(sampler.current if sampler.markov else None)
        if channel_draws(self.ctx):  # the links' states as the kernel left them, and the steps (`_run_held`'s own)
            step = channel.step if self.holds else channel.step + T
            channel = channel._replace(links=sampler.links.copy(), step=step)
        own = self.args.own
        final = dict(zip(self.own_names, own)) | dict(zip(messages, self.buffers[self.newest][:, :, : self.N]))
        new = state._make(back(final[f]) for f in state._fields)
        sums = back(self.args.sums)
        if self.holds:  # counted as they were carried (`_run_held`)
            return new, channel, sums
        # every arc that delivers carries every message (`_step_edges` counted them)
        return new, counted(channel, sampler.n_up.astype(np.float64), len(messages), len(messages) * q), sums


run_block.draws_samples = True  # type: ignore[attr-defined]  # the run loop may hand it `Draws`, not a `Block`


def _run_held(ctx, compiled, args, buffers, alphas, blk, channel, t0=0, t1=None, first=0):
    """Steps t0 .. t1 - 1 of the block (all of it by default; those of step t0 in buffer ``first``) over a channel
    whose receivers hold copies (`_seeds_held`), the seeds in as many threads as there are cores; returns (which
    buffer holds the newest messages, the channel's new state)."""
    from dgtd.backends.compiled.held import Held, Links
    from dgtd.channels.imperfect import held

    sums, graph, N = args.sums, args.graph, ctx.network.n_nodes
    q = sums.shape[2]
    t1 = alphas.shape[0] if t1 is None else t1
    sampler, alphas = _piece_of(args.sampler, blk, t0, t1), alphas[t0:t1]
    link = ctx.channel
    M, B, A, T = buffers.shape[1], sums.shape[0], ctx.arcs.n_arcs, alphas.shape[0]
    Q = M * q
    channel = held(channel, A, Q, link.delay)
    order = storage_order(ctx)
    src_row = ctx.arcs.src if order is None else order[1][ctx.arcs.src]
    links = Links(
        np.zeros(0) if link.wake is None else np.ascontiguousarray(link.wake, np.float64),
        int(link.delay),
        int(link.bits),
        0 if link.top_k is None else int(link.top_k),
        int(link.error_feedback),
        q,
        np.ascontiguousarray(ctx.arcs.src, np.int64),
        np.ascontiguousarray(src_row, np.int64),
        *entity_ids(ctx)[1:3],
        *link_keys_of(ctx, sampler.rng[:, 0]).values(),
    )
    state = Held(
        channel.copies.copy(),
        channel.since.copy(),
        channel.pending.copy(),
        channel.due.copy(),
        channel.posted.copy(),
        channel.step.copy(),
        channel.per_arc.copy(),
        np.zeros(B, np.int64),
    )
    graph = graph._replace(nbr=N + graph.eid)  # a neighbour's messages: its arc's copy, row N + a
    kernel = _held_driver(compiled)
    n_obs, degree = sampler.current.shape[1], _max_degree(graph.indptr)
    threads = max(1, min(get_num_threads(), B)) if T * B * N >= THREADED_WORK else 1
    groups = np.linspace(0, B, threads + 1).astype(int)

    def run(b0, b1):
        shared = _space(1, 1, n_obs, N, A, degree, q, M, compiled.work)._replace(degree=_private((1, N + A), np.int64))
        space = HeldSpace(  # type: ignore[call-arg]
            *shared,
            awake=_private((N,), np.bool_),
            late=_private((A,), np.int64),
            rounding=_private((A, Q), np.float64),
            value=_private((Q,), np.float64),
            chosen=_private((Q,), np.bool_),
        )
        x = _samples(args, space)
        kernel(
            args.p, args.own, sums, buffers, first, alphas, sampler, args.feat, x, graph, space, links, state, b0, b1
        )

    if threads == 1:
        run(0, B)
    else:
        if not _POOL or _POOL[0]._max_workers != get_num_threads():
            _POOL[:] = [ThreadPoolExecutor(get_num_threads(), thread_name_prefix="dgtd-seeds")]
        for job in [_POOL[0].submit(run, int(b0), int(b1)) for b0, b1 in zip(groups[:-1], groups[1:])]:
            job.result()
    bits = M * link.vector_bits(q)
    delivered = state.delivered.astype(np.float64)
    channel = channel._replace(
        messages=channel.messages + delivered * M,
        bits=channel.bits + delivered * bits,
        copies=state.copies,
        since=state.since,
        pending=state.pending,
        due=state.due,
        posted=state.posted,
        step=state.step,
        per_arc=state.per_arc,
    )
    return (first + T) % 2, channel


def _held_driver(compiled: CompiledStep):
    """`_seeds_held` compiled for an algorithm's step (once, cached on disk), as `driver` compiles the others."""
    key = ("held", compiled.key)
    if key not in _DRIVERS:
        space, suffix = _template_space(compiled), "held_" + compiled.key
        compiled_copy(_learner, space, suffix, inline="always")
        _DRIVERS[key] = compiled_copy(_seeds_held, space, suffix, compiled.cache, nogil=True)
        load_quickly(_DRIVERS[key])
    return _DRIVERS[key]


def arc_weights_of(channel) -> np.ndarray:
    """1 / (1 - loss_a) per arc where a lossy channel reweighs what is heard (`dgtd.channels.Lossy`), else nothing."""
    if not getattr(channel, "reweight", False):
        return np.zeros(0)
    return np.ascontiguousarray(channel.arc_weights, dtype=np.float64)


def _graph(ctx, messages: bool) -> Graph:
    """(CSR indptr, neighbours, link ids, the agent of each row, each arc's weight where the channel weighs what is
    heard (`dgtd.channels.Lossy.reweight`), else nothing): in storage rows for an algorithm that sends, else the
    agents' own numbering (it reads no neighbours). A link id is the edge's id, or on a channel that draws events
    per arc the id of the arc into the row's agent (`dgtd.channels.Arcs`: 2e + 1 when that agent is the larger end
    of edge e), which is what the step's mask of links up (`_step_edges`) holds then."""
    indptr, nbr, eid, agent_of = (
        storage_graph(ctx) if messages else (*graph_arrays(ctx), np.arange(ctx.network.n_nodes, dtype=np.int64))
    )
    if not channel_draws(ctx):
        return Graph(indptr, nbr, eid, agent_of, np.zeros(0))
    agent = np.repeat(agent_of, np.diff(indptr))  # the receiving agent of every CSR entry
    return Graph(indptr, nbr, 2 * eid + (agent == ctx.arcs.dst[2 * eid + 1]), agent_of, arc_weights_of(ctx.channel))


class Layouts:
    """How one run spreads its work: seeds one after another or several at once ("seeds"), or the agents of each seed
    spread over the cores at every step ("agents"), where that can pay (few seeds, many agents, an algorithm that
    sends). Where both fit, the block runs in pieces of about ``PIECE_SECONDS``, each in the layout measured faster so
    far (the agent layout until measured), the other measured again every ``RECHECK_SECONDS``: every step waits for
    the slowest core in the agent layout, and on a core shared with another busy process that is a step of the other
    process's time slice (measured: 10x slower), while the seeds layout keeps the speed of one core. A piece shorter
    than ``MIN_MEASURED`` measures mostly the start of a call, and is not counted; nor is the agent layout's first
    piece, which pays its threads' start-up (its first 0.1 s ran at half its speed, measured). Every layout runs the
    same steps in the same order, so the numbers do not depend on the choice."""

    PIECE_SECONDS = 0.1
    RECHECK_SECONDS = 2.0
    MIN_MEASURED = 0.02
    CHECK_SECONDS = 0.03  # a piece run to measure the layout not in use: short, as it is likely the slower

    def __init__(self, candidates: tuple[str, ...], agent_steps_per_step: int):
        self.candidates, self.per_step = candidates, max(1, agent_steps_per_step)
        self.rate: dict[str, float] = {}
        self.since_check, self.started = 0.0, set[str]()
        self.spaces: dict = {}  # (layout, job) -> (dimensions, `_space`): made once per run, not once per block

    def run(self, kernels, args, buffers, alphas, blk, n_messages: int, n_work: int, t0=0, T=None, newest=0) -> int:
        """Steps t0 .. T - 1 of the block (all of it by default), piece by piece, the messages of step t0 in buffer
        ``newest``; returns which of the two buffers holds the newest messages."""
        if alphas.shape[0] == 0:  # an empty block (the run's first): load or compile every layout it may use
            for layout in self.candidates:
                self._call(kernels, layout, args, buffers, 0, alphas, blk, 0, 0, n_messages, n_work)
            return 0
        T = alphas.shape[0] if T is None else T
        while t0 < T:
            layout = self._choose()
            steps = T - t0 if len(self.candidates) == 1 else self._piece(layout, T - t0)
            start = time.perf_counter()
            self._call(kernels, layout, args, buffers, newest, alphas, blk, t0, t0 + steps, n_messages, n_work)
            seconds = time.perf_counter() - start
            if seconds >= self.MIN_MEASURED:
                if layout != "agents" or layout in self.started:
                    self.rate[layout] = steps * self.per_step / seconds
                self.started.add(layout)
            self.since_check += seconds
            newest = (newest + steps) % 2
            t0 += steps
        return newest

    def _choose(self) -> str:
        measured = [c for c in self.candidates if c in self.rate]
        if not measured:
            return self.candidates[0]  # until it is measured twice
        if len(measured) < len(self.candidates) or self.since_check >= self.RECHECK_SECONDS:
            self.since_check = 0.0  # measure the other (again): the machine's load may have changed
            return min(self.candidates, key=lambda c: self.rate.get(c, 0.0))
        return max(self.candidates, key=lambda c: self.rate[c])

    def _piece(self, layout: str, left: int) -> int:
        checking = bool(self.rate) and layout != max(self.rate, key=lambda c: self.rate[c])
        rate = self.rate.get(layout, min(self.rate.values(), default=2e6))
        seconds = self.CHECK_SECONDS if checking else self.PIECE_SECONDS
        return int(min(left, max(1, seconds * rate / self.per_step)))

    def _space(self, key, *dimensions) -> tuple:
        if key not in self.spaces or self.spaces[key][0] != dimensions:
            self.spaces[key] = dimensions, _space(*dimensions)
        return self.spaces[key][1]

    def _call(self, kernels, layout, args, buffers, first, alphas, blk, t0, t1, n_messages, n_work):
        _seeds, _agents = kernels
        sampler, sums, graph, alphas = _piece_of(args.sampler, blk, t0, t1), args.sums, args.graph, alphas[t0:t1]
        # up_t holds a step's edges up, or on a lossy channel its arcs that deliver (2E: `_step_edges`)
        B, N, q = sums.shape[0], buffers.shape[3], sums.shape[2]
        n_obs, degree = sampler.current.shape[1], _max_degree(graph.indptr)
        E = graph.eid.shape[0] if sampler.loss.shape[0] else graph.eid.shape[0] // 2
        if layout == "agents":
            chunks = 4 * get_num_threads()
            space = self._space("agents", 2 * B, chunks, n_obs, N, E, degree, q, n_messages, n_work)
            x = _samples(args, space)
            _agents(args.p, args.own, sums, buffers, first, alphas, sampler, args.feat, x, graph, space, chunks)
            return
        threads = min(get_num_threads(), B)
        if threads <= 1 or (t1 - t0) * self.per_step < THREADED_WORK:
            space = self._space(0, 1, 1, n_obs, N, E, degree, q, n_messages, n_work)
            x = _samples(args, space)
            _seeds(args.p, args.own, sums, buffers, first, alphas, sampler, args.feat, x, graph, space, 0, B)
            return
        # seeds in small groups taken by whichever thread is free: a thread slowed by another process takes fewer.
        # Each seed's trajectory states, written at every step, get cache lines of their own.
        current = sampler.current
        states = _private(current.shape, np.int64)
        states[...] = current
        sampler = sampler._replace(current=states)
        if not _POOL or _POOL[0]._max_workers != threads:
            _POOL[:] = [ThreadPoolExecutor(threads, thread_name_prefix="dgtd-seeds")]
        work = (t1 - t0) * self.per_step
        n_groups = min(B, GROUPS_PER_THREAD * threads, max(threads, work // JOB_WORK))
        groups = np.linspace(0, B, n_groups + 1).astype(int)
        jobs = []
        for j, (b0, b1) in enumerate(zip(groups[:-1], groups[1:])):
            space = self._space(j, 1, 1, n_obs, N, E, degree, q, n_messages, n_work)
            kernel_args = (args.p, args.own, sums, buffers, first, alphas, sampler, args.feat, _samples(args, space))
            jobs.append(_POOL[0].submit(_seeds, *kernel_args, graph, space, int(b0), int(b1)))
        for job in jobs:
            job.result()
        current[...] = states


class Space(NamedTuple):
    """The arrays a kernel works in (`_space`)."""

    s: np.ndarray  # (steps, n_obs): rows of a step's samples
    a: np.ndarray
    s_next: np.ndarray
    r: np.ndarray  # (steps, N)
    up: np.ndarray  # (steps, E or 2E): the edges up, or the arcs that deliver
    heard: np.ndarray  # (threads, degree): the neighbours heard
    n_heard: np.ndarray  # (threads, 1): how many
    weights: np.ndarray  # (threads, degree): their weights
    degree: np.ndarray  # (steps, N): every agent's count of messages heard
    scratch: np.ndarray  # (messages, threads, q): the inbox's aggregates
    work: np.ndarray  # (work rows, threads, q): the step's work rows


HeldSpace = NamedTuple(  # type: ignore[misc]
    "HeldSpace", [(name, np.ndarray) for name in (*Space._fields, "awake", "late", "rounding", "value", "chosen")]
)
HeldSpace.__doc__ = """`Space` (its degree (1, N + A): a copy's row counts as its sender's) and the arrays of a channel
whose receivers hold copies (`dgtd.backends.compiled.held.carry`): awake (N,), late (A,), rounding (A, Q), value and
chosen (Q,)."""


class Graph(NamedTuple):
    """The network as the kernels read it (`_graph`)."""

    indptr: np.ndarray  # CSR rows of each storage row's neighbours
    nbr: np.ndarray  # each neighbour's row in the message buffers
    eid: np.ndarray  # each entry's link id (edge, or arc where the channel draws per arc)
    agent_of: np.ndarray  # the agent of each row
    arc_weights: np.ndarray  # each arc's weight where the channel weighs what is heard, else empty


class Args(NamedTuple):
    """A block's arguments to the kernels besides the layout's own (`Advance`)."""

    p: tuple  # the algorithm's `params`
    own: np.ndarray  # (fields kept, B, L, q)
    sums: np.ndarray  # (B, L, q): the running sums of w
    sampler: Sampler
    feat: Features
    ratio: np.ndarray  # the rows' ratio table
    continuing: np.ndarray  # the rows' continuing flags
    gamma: float
    graph: Graph


def _samples(args: Args, space) -> Samples:
    """The kernels' samples record: the step rows of ``space``, the rows' tables of ``args``."""
    return Samples(space.s, space.a, space.s_next, space.r, 0, args.ratio, args.continuing, args.gamma)


def _space(
    steps: int, threads: int, n_obs: int, N: int, E: int, degree: int, q: int, n_messages: int, n_work: int
) -> Space:
    """The arrays a kernel works in: ``steps`` rows of a step's samples (s, a, s' (n_obs), r (N), edges up (E)) and of
    every agent's count of messages heard (N); per thread, the neighbours heard (``degree`` at most), how many and
    their weights, the inbox's aggregates (messages, threads, q) and the step's work rows (work, threads, q). Each
    array has cache lines of its own, and each thread's rows too (rows padded to whole lines): they are written at
    every agent-step, and a line two threads write in turn moves between their cores at every write (measured: two
    threads over seeds ran at 1.3x one thread with the arrays of one next to the other's, against 1.8x apart)."""
    lines = lambda width, dtype: -(-width * np.dtype(dtype).itemsize // LINE) * LINE // np.dtype(dtype).itemsize  # noqa: E731
    return Space(
        _private((steps, n_obs), np.int64),
        _private((steps, n_obs), np.int64),
        _private((steps, n_obs), np.int64),
        _private((steps, N), np.float64),
        _private((steps, E), np.bool_, 1),
        _private((threads, lines(degree, np.int64)), np.int64),
        _private((threads, lines(1, np.int64)), np.int64),
        _private((threads, lines(degree, np.float64)), np.float64),
        _private((steps, N), np.int64),
        _private((n_messages, threads, lines(q, np.float64)), np.float64),
        _private((n_work, threads, lines(q, np.float64)), np.float64),
    )


LINE = 64  # bytes in a cache line


def _private(shape: tuple, dtype, fill=0) -> np.ndarray:
    """A C-contiguous array filled with ``fill`` that starts on a cache line and shares none with any other array."""
    n, size = int(np.prod(shape)), np.dtype(dtype).itemsize
    pad = LINE // size
    buffer = np.full(n + 3 * pad, fill, dtype)
    start = (-buffer.ctypes.data // size) % pad + pad  # the next line boundary, and a whole line before it
    return buffer[start : start + n].reshape(shape)


def _max_degree(indptr: np.ndarray) -> int:
    return max(1, int(np.diff(indptr).max(initial=0)))


def _piece_of(sampler: Sampler, blk, t0: int, t1: int) -> Sampler:
    """The sampling arguments of steps t0 .. t1 - 1 of the block: the keyed streams from step t0 on, and a
    materialised block's arrays from step t0 on."""
    if t0 == 0:
        return sampler
    rng = sampler.rng.copy()
    rng[:, 1] += np.uint64(t0)
    if isinstance(blk, Draws):
        return sampler._replace(rng=rng)
    up = sampler.up[t0:] if sampler.up.shape[0] else sampler.up
    return sampler._replace(
        rng=rng, s=sampler.s[t0:], a=sampler.a[t0:], s_next=sampler.s_next[t0:], r=sampler.r[t0:], up=up
    )


def _layouts(ctx, B: int, L: int, q: int, messages: bool) -> Layouts:
    """The run's `Layouts` (kept on the run's context, so that what it measured carries from block to block)."""
    candidates: tuple[str, ...]
    if LAYOUT != "auto":
        candidates = (LAYOUT,) if messages or LAYOUT == "seeds" else ("seeds",)
    elif messages and B < get_num_threads() and L * q >= AGENTS_MIN_WORK:
        candidates = ("agents", "seeds")
    else:
        candidates = ("seeds",)
    return per_run(ctx, f"layouts-{candidates}", lambda: Layouts(candidates, B * L))


def feature_arrays(ctx, blk=None):
    """(Phi, sparse, CSR rows of Phi): sparse when rows hold at most a quarter of the features (tabular: one); the
    sparse steps read the features from the CSR rows only, and get a row of zeros for Phi. The model's, once per run;
    a block's own rows (`SampleTable`), for that block."""

    def build(Phi=ctx.Phi):
        Phi = np.ascontiguousarray(Phi, dtype=np.float64)
        rows, cols = np.nonzero(Phi)  # row-major order: CSR rows without importing scipy.sparse
        indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=Phi.shape[0]))]).astype(np.int64)
        sparse = rows.size <= Phi.size // 4
        dense = readonly(np.zeros((1, Phi.shape[1])) if sparse else Phi)  # read-only, as the model's Phi is
        return dense, sparse, indptr, cols.astype(np.int64), Phi[rows, cols].astype(np.float64)

    if getattr(blk, "table", None) is not None:
        return build(rows_of(ctx, blk)[0])
    return per_run(ctx, "phi", build)


def rows_of(ctx, blk) -> tuple:
    """(Phi, ratio table) the block's indices point into: its own rows (`SampleTable`), else the model's; a `Draws`
    (samples drawn inside the kernel from the model) has no rows of its own."""
    table = getattr(blk, "table", None)
    return (ctx.Phi, ctx.ratio) if table is None else (table.phi, table.ratio)


def readonly(x) -> np.ndarray:
    """A C-contiguous float64 read-only view, as the model's arrays are: numba compiles a kernel once per array
    type, and a writable array is another type, so a block's own rows would otherwise cost a second compilation."""
    view = np.ascontiguousarray(x, np.float64).view()
    view.setflags(write=False)
    return view


def continuing_flags(ctx, blk: Block | None = None) -> np.ndarray:
    """c of the rows the block's indices point into: 0 at an episodic task's terminal states (or, for a block with its
    own `SampleTable`, at the next state of a transition that ended an episode), 1 elsewhere."""
    table: SampleTable | None = getattr(blk, "table", None)  # a `Draws` (samples drawn inside the kernel) has none
    if table is not None:
        return readonly(table.continuing)
    return readonly(np.ones(ctx.Phi.shape[0]) if ctx.continuing is None else ctx.continuing)
