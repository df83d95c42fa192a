"""Compiled sampling (numba): uniforms into samples with exactly the arithmetic of the NumPy reference
(`dgtd.sources.model.alias_pick`, `reward_from_uniform`), either for a whole block (`block_from_uniforms`, used
by the baseline kernels and simulators) or step by step inside a kernel that draws its own uniforms from the keyed
streams (`_step_samples`, `sample_args`; `dgtd.streams`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit, prange

from dgtd.backends.compiled.cache import load_quickly
from dgtd.backends.compiled.graph import per_run
from dgtd.backends.compiled.rng import keyed_pair
from dgtd.samples import Block, Draws
from dgtd.streams import AGENT_STATE, ARC_LOSS, EDGE_UP, REWARD, SHARED_STATE, arc_side, link_keys

NOISE_CODES = {"none": 0, "bernoulli": 1, "uniform": 2, "transition": 0}  # a transition's reward: deterministic


@njit(cache=True, inline="always")
def _alias(prob, alias, u):
    K = prob.shape[0]
    x = u * K
    j = min(np.int64(x), K - 1)
    other = alias[j]  # read first, so that the choice compiles to a conditional move, not a branch taken at random
    return j if x - j < prob[j] else other


@njit(cache=True, inline="always")
def _alias_row(prob, alias, row, u):
    """`_alias` on row ``row`` of 2-D tables, indexed in place (a row view would cost an atomic reference count)."""
    K = prob.shape[1]
    x = u * K
    j = min(np.int64(x), K - 1)
    other = alias[row, j]  # as in `_alias`
    return j if x - j < prob[row, j] else other


@njit(cache=True, inline="always")
def _divmod(j, S, inv_S):
    """(j // S, j % S) for 0 <= j < 2^52 and S > 0 without a division instruction (tens of cycles): the float
    quotient is off by at most one, which the remainder corrects."""
    a = np.int64(np.float64(j) * inv_S)
    r = j - a * S
    a = a + 1 if r >= S else (a - 1 if r < 0 else a)
    return a, j - a * S


@njit(cache=True, inline="always")
def _transition(u_s, u_sa, sampler, current, b, o, S):
    """(s, a, s') of observation o of seed b from its two uniforms: s ~ d from u_s (i.i.d.) or the trajectory's
    current state (Markovian, which then moves to s'), and (a, s') from u_sa: the table's flat index a * S + s'.
    Where restarts are not samples (``terminal`` holds the S flags, else nothing), a trajectory that reaches a
    terminal s' goes on from the restart's state, drawn from u_s (`dgtd.sources.model.next_current`). ``current``
    is the record's, passed apart: it is written, and a parallel loop may not write through a record."""
    sa_prob, sa_alias, terminal = sampler.sa_prob, sampler.sa_alias, sampler.terminal
    s = current[b, o] if sampler.markov else _alias(sampler.d_prob, sampler.d_alias, u_s)
    a, sn = _divmod(_alias_row(sa_prob, sa_alias, s, u_sa), S, 1.0 / S)
    if sampler.markov:
        current[b, o] = sn
        if terminal.shape[0] > 0 and terminal[sn]:
            current[b, o] = _divmod(_alias_row(sa_prob, sa_alias, sn, u_s), S, 1.0 / S)[1]
    return s, a, sn


@njit(cache=True, inline="always")
def _reward(mean, sigma, noise, u):
    if noise == 0:
        return mean
    if noise == 1:
        return sigma if u < mean / sigma else 0.0
    h = min(mean, sigma - mean)
    return mean + h * (2.0 * u - 1.0)


@njit(cache=True, parallel=True)
def _sample_kernel(u_state, u_reward, u_edge, sampler):
    """Samples of a block from its uniforms, into the block arrays of ``sampler`` (s, a, s_next, r, up): each
    (seed, observation) pair runs its own trajectory, so they are spread over the cores."""
    T, B, n_obs, width = u_state.shape
    # arrays taken out of the record first: numba 0.68 loses a parallel loop's stores through a record's field
    s_out, a_out, sn_out, r_out, up_out = sampler.s, sampler.a, sampler.s_next, sampler.r, sampler.up
    current = sampler.current
    rewards, sigma, noise, p_edge = sampler.rewards, sampler.sigma, sampler.noise, sampler.p_edge
    N, S = rewards.shape[0], rewards.shape[1]
    for flat in prange(B * n_obs):
        b = flat // n_obs
        o = flat % n_obs
        for t in range(T):
            s, a, sn = _transition(u_state[t, b, o, 0], u_state[t, b, o, width - 1], sampler, current, b, o, S)
            s_out[t, b, o] = s
            a_out[t, b, o] = a
            sn_out[t, b, o] = sn
            # Rewards of the agents that see this observation: agent o, or all agents on a shared trajectory.
            lo, hi = (o, o + 1) if n_obs == N else (0, N)
            for i in range(lo, hi):
                r = rewards[i, s, a, sn if rewards.shape[3] > 1 else 0]  # (`Problem.reward_table`)
                r_out[t, b, i] = _reward(r, sigma, noise, u_reward[t, b, i]) if noise != 0 else r
    E = p_edge.shape[0]
    if up_out.shape[0] > 0:
        for flat in prange(T * B):
            t = flat // B
            b = flat % B
            for e in range(E):
                up_out[t, b, e] = u_edge[t, b, e] < p_edge[e]


load_quickly(_sample_kernel)


def block_from_uniforms(problem, network, tables, U: dict, current, agents=None, edges=None):
    """Compiled twin of `dgtd.sources.model.block_from_uniforms`."""
    T, B, n_obs, _ = U["state"].shape
    table, p = problem.reward_table, np.asarray(network.p, dtype=np.float64)
    if agents is not None:
        table, p = table[agents], p[edges]
    N = table.shape[0]
    markov = current is not None
    cur = np.array(current, dtype=np.int64) if markov else np.zeros((1, 1), np.int64)
    s, a, sn = (np.empty((T, B, n_obs), np.int64) for _ in range(3))
    r = np.empty((T, B, N))
    up = np.empty((T, B, p.shape[0]), np.bool_) if "edge" in U else np.empty((0, 0, 0), np.bool_)
    sampler = Sampler(
        fused=False,
        rng=np.zeros((B, 2), np.uint64),
        markov=markov,
        current=cur,
        **_model(tables, problem, markov, table),
        p_edge=frozen(p, np.float64),
        **_no_loss(B),
        s=s,
        a=a,
        s_next=sn,
        r=r,
        up=up,
        n_up=np.zeros(B, np.int64),
        **_ids(entities(*(np.zeros(0, np.int64),) * 3, shared=n_obs < N)),
        **_no_keys(B),
    )
    _sample_kernel(
        np.ascontiguousarray(U["state"]),
        U.get("reward", np.zeros((0, 0, 0))),
        U.get("edge", np.zeros((0, 0, 0))),
        sampler,
    )
    return Block(s, a, sn, r, up if "edge" in U else None), (cur if markov else None)


class Sampler(NamedTuple):
    """What the compiled kernels draw or copy a step's samples from (`sample_args`): one flat record, as numba hands
    a parallel loop records of arrays and numbers only."""

    fused: bool  # draw from the keyed streams (a `Draws`), or copy a block's samples (s, a, s_next, r, up)
    rng: np.ndarray  # (B, 2) uint64: each seed's key and the block's first step (`dgtd.streams`)
    markov: bool  # trajectories (``current`` their states), or s ~ d at every step
    current: np.ndarray  # (B, n_obs) int64
    d_prob: np.ndarray  # alias tables of d (S,) and of (a, s') given s (S, A S') (`SamplerTables`)
    d_alias: np.ndarray
    sa_prob: np.ndarray
    sa_alias: np.ndarray
    terminal: np.ndarray  # (S,) bool where restarts are not samples (`restart_flags`), else empty
    rewards: np.ndarray  # (N, S, A, S' or 1): `Problem.reward_table`
    sigma: float
    noise: int  # `NOISE_CODES`
    p_edge: np.ndarray  # (E,) each edge's probability of being up; empty for a fixed graph
    loss: np.ndarray  # (0 | 1 | 2, 2E): the arcs' loss (and burst) probabilities (`_step_edges`)
    links: np.ndarray  # (B, 2E) uint8: 1 while an arc's burst chain is losing
    s: np.ndarray  # a block's samples (T, B, n_obs), (T, B, N), (T, B, E), where not fused
    a: np.ndarray
    s_next: np.ndarray
    r: np.ndarray
    up: np.ndarray
    n_up: np.ndarray  # (B,) int64: how many arcs delivered, as the kernels count them
    obs_ids: np.ndarray  # the entities' ids in the whole network (`entity_ids`): empty where each index is its id
    agent_ids: np.ndarray
    counted: np.ndarray  # (2E,) uint8: 1 for each arc the counts count; empty: every arc
    edge_keys: np.ndarray  # (B, E) uint64: each edge's key (`dgtd.streams.link_keys`) where its links are drawn
    arc_side: np.ndarray  # (2E,) uint8: each arc's side of its link, the number of the call it takes (`arc_side`)
    purpose: int  # the states' stream: one trajectory for all agents or one each (`dgtd.streams`)


@njit(cache=True)
def _sample_step(sampler, b, row, t, space):
    """Step t's samples of seed b into row ``row`` of the step arrays of ``space`` (s, a, s_next, r: observations
    and agents; up: edges, or arcs on a lossy channel); returns how many arcs deliver (those ``counted`` counts).

    Fused: drawn here from seed b's keyed streams (``rng`` [b] = (its key, the block's first step): each number a
    function of the purpose, the observation, agent, edge or arc, and the step, as `dgtd.sources.model.Streams.draw`
    draws them) and turned into samples with the arithmetic of `block_from_uniforms`, so the NumPy reference sees
    the same samples. Otherwise copied from a block (samples from a simulator). The two halves,
    `_step_observations` and `_step_edges`, write disjoint arrays: a kernel may run them at the same time."""
    _observations(sampler, b, row, t, space.s, space.a, space.s_next, space.r, 0, space.s.shape[1])
    return _edges(sampler, b, row, t, space.up)


@njit(cache=True)
def _step_observations(sampler, b, row, t, s_t, a_t, sn_t, r_t, o0, o1):
    """`_observations`, compiled once for the agent layout's chunks (`_sample_step` inlines it: one call a step)."""
    _observations(sampler, b, row, t, s_t, a_t, sn_t, r_t, o0, o1)


@njit(cache=True)
def _step_edges(sampler, b, row, t, up_t):
    """`_edges`, compiled once for the agent layout's chunks."""
    return _edges(sampler, b, row, t, up_t)


@njit(cache=True, inline="always")
def _observations(sampler, b, row, t, s_t, a_t, sn_t, r_t, o0, o1):
    """The states, actions, next states and rewards of `_sample_step` (seed b's state and reward streams), each
    drawn by its observation's and agent's ids in the whole network (`entity_ids`): those of observations o0 .. o1 - 1
    and their agents (every agent where they share one observation), so that several threads can draw a step's."""
    obs_ids, agent_ids, R_sample, noise = sampler.obs_ids, sampler.agent_ids, sampler.rewards, sampler.noise
    n_obs = s_t.shape[1]
    N = r_t.shape[1]
    S = R_sample.shape[1]
    i0, i1 = (o0, o1) if n_obs == N else (0, N if o0 == 0 < o1 else 0)  # a shared observation's: with observation 0
    if not sampler.fused:
        for o in range(o0, o1):
            s_t[row, o], a_t[row, o], sn_t[row, o] = sampler.s[t, b, o], sampler.a[t, b, o], sampler.s_next[t, b, o]
        for i in range(i0, i1):
            r_t[row, i] = sampler.r[t, b, i]
        return
    key, step = sampler.rng[b, 0], sampler.rng[b, 1] + np.uint64(t)
    for o in range(o0, o1):
        u_s, u_sa = keyed_pair(key, sampler.purpose, step, o if obs_ids.shape[0] == 0 else obs_ids[o], 0)
        s_t[row, o], a_t[row, o], sn_t[row, o] = _transition(u_s, u_sa, sampler, sampler.current, b, o, S)
    u_even = u_odd = 0.0
    pair = -1
    for i in range(i0, i1):
        o = i if n_obs == N else 0
        r = R_sample[
            i, s_t[row, o], a_t[row, o], sn_t[row, o] if R_sample.shape[3] > 1 else 0
        ]  # (`Problem.reward_table`)
        if noise != 0:  # agents 2j and 2j + 1 share call j (`dgtd.streams.singles`)
            agent = i if agent_ids.shape[0] == 0 else agent_ids[i]
            if agent >> 1 != pair:
                pair = agent >> 1
                u_even, u_odd = keyed_pair(key, REWARD, step, pair, 0)
            r = _reward(r, sampler.sigma, noise, u_even if agent & 1 == 0 else u_odd)
        r_t[row, i] = r


@njit(cache=True, inline="always")
def _edges(sampler, b, row, t, up_t):
    """Which links deliver at step t, for `_sample_step` (seed b's edge stream): into row ``row`` of up_t, each
    edge up (E), or where the channel loses messages each arc that delivers (2E: its edge up and its message kept,
    from the pair of uniforms of each edge's two arcs at the step, as `dgtd.channels.Lossy` draws them). ``loss`` is
    empty on a perfect channel, else row 0 holds each arc's loss probability (i.i.d. losses) or, with bursts, the
    probability that its chain enters its losing state, and row 1 that it leaves it; ``links`` [b, a] is 1 while arc
    a's chain is losing. Each edge draws by its key (``edge_keys``: the agents it joins), its arcs by their sides.
    Returns how many arcs deliver of those ``counted`` (two per edge up, without loss, in a whole network)."""
    loss, links, counted, p_edge = sampler.loss, sampler.links, sampler.counted, sampler.p_edge
    if loss.shape[0] == 0:
        return _edges_up(sampler, b, row, t, up_t)
    E = loss.shape[1] // 2
    bursty = loss.shape[0] == 2
    fused = sampler.fused
    drawn = fused and p_edge.shape[0] == E  # random edges drawn here; a fixed graph draws nothing
    step = sampler.rng[b, 1] + np.uint64(t)
    n = 0
    for e in range(E):
        up = True
        if drawn:
            up = keyed_pair(sampler.edge_keys[b, e], EDGE_UP, step, 0, 0)[0] < p_edge[e]
        elif not fused and sampler.up.shape[0] > 0:
            up = sampler.up[t, b, e]
        u0, u1 = keyed_pair(sampler.edge_keys[b, e], ARC_LOSS, step, 0, 0)
        for a in range(2 * e, 2 * e + 2):
            u = u0 if sampler.arc_side[a] == 0 else u1
            if bursty:
                losing = u >= loss[1, a] if links[b, a] == 1 else u < loss[0, a]
                links[b, a] = 1 if losing else 0
                kept = up and not losing
            else:
                kept = up and u >= loss[0, a]
            up_t[row, a] = kept
            n += kept * (1 if counted.shape[0] == 0 else counted[a])
    return n


@njit(cache=True, inline="always")
def _edges_up(sampler, b, row, t, up_t):
    """Each edge up at step t into row ``row`` of up_t (a perfect channel's `_step_edges`); returns how many of
    their arcs ``counted`` counts (2 per edge up in a whole network)."""
    E = up_t.shape[1]
    p_edge, counted, fused, up_blk = sampler.p_edge, sampler.counted, sampler.fused, sampler.up
    if fused and p_edge.shape[0] == E:  # random edges drawn here, each by its link key; a fixed graph draws nothing
        step = sampler.rng[b, 1] + np.uint64(t)
        keys = sampler.edge_keys[b]
        for e in range(E):
            up_t[row, e] = keyed_pair(keys[e], EDGE_UP, step, 0, 0)[0] < p_edge[e]
    elif not fused and up_blk.shape[0] > 0:
        for e in range(E):
            up_t[row, e] = up_blk[t, b, e]
    drawn = (fused and p_edge.shape[0] == E) or (not fused and up_blk.shape[0] > 0)
    n = 0
    for e in range(E):
        up = up_t[row, e] if drawn else True
        n += up * (2 if counted.shape[0] == 0 else counted[2 * e] + counted[2 * e + 1])
    return n


def up_mask(blk: Block):
    """The block's edge mask, or an empty one for a fixed graph (one compiled signature for both)."""
    return np.empty((0, 0, 0), np.bool_) if blk.up is None else np.ascontiguousarray(blk.up)


def channel_draws(ctx) -> bool:
    """Whether the run's channel draws events per arc (a lossy one: `dgtd.channels.base.Channel.draws`), which the
    kernels then draw in `_step_edges`."""
    return ctx.channel.draws


def sample_args(ctx, blk, B: int, channel=None) -> Sampler:
    """The compiled driver's `Sampler`: draw in the kernel from a `Draws`' streams, or copy a `Block`. The tables a
    kernel only reads are handed over read-only and the samples it copies writable, whichever source they come from:
    numba compiles a kernel once per array type, and a read-only array is another type."""
    none_i, none_f, none_b = np.zeros((0, 0, 0), np.int64), np.zeros((0, 0, 0)), np.zeros((0, 0, 0), np.bool_)
    p_edge = np.zeros(0)
    samples: dict  # the block's arrays, of `Sampler`'s fields s .. up
    if isinstance(blk, Draws):
        src = blk.source
        markov = src.current is not None
        current = np.array(src.current, dtype=np.int64) if markov else np.zeros((B, src.n_obs), np.int64)
        if not ctx.network.fixed:
            p_edge = np.asarray(ctx.network.p, dtype=np.float64)
        samples = dict(s=none_i, a=none_i, s_next=none_i, r=none_f, up=none_b)
        fused, rng = True, src.streams.cursor()
    else:
        markov, current = False, np.zeros((B, blk.s.shape[2]), np.int64)
        samples = dict(
            s=writable(blk.s, np.int64),
            a=writable(blk.a, np.int64),
            s_next=writable(blk.s_next, np.int64),
            r=writable(blk.r, np.float64),
            up=writable(up_mask(blk), np.bool_),
        )
        fused, rng = False, np.zeros((B, 2), np.uint64)
    links = _no_loss(B)
    if channel_draws(ctx):  # the channel's events, keyed by the same seeds and steps as the samples
        lossy = ctx.channel
        if lossy.burst is None:
            loss = lossy.loss[None, :]
        else:
            loss = np.stack([lossy.enter, np.full(lossy.loss.shape, 1.0 / float(lossy.burst))])
            links["links"] = np.array(channel.links, dtype=np.uint8, order="C")
        links["loss"] = frozen(loss, np.float64)
        rng = channel_cursor(channel, rng, fused)
    keyed = link_keys_of(ctx, rng[:, 0]) if (fused and p_edge.shape[0] > 0) or channel_draws(ctx) else _no_keys(B)
    return Sampler(
        fused=fused,
        rng=rng,
        markov=markov,
        current=current,
        **_model(ctx.tables, ctx.problem, markov),
        p_edge=frozen(p_edge, np.float64),
        **links,
        **samples,
        n_up=np.zeros(B, np.int64),
        **_ids(entity_ids(ctx)),
        **keyed,
    )


def link_keys_of(ctx, keys: np.ndarray) -> dict:
    """The `Sampler`'s ``edge_keys`` (B, E) under seeds' keys (B,), each edge's the key of the agents it joins in the
    whole network (`dgtd.streams.link_keys`; a rank's rows name theirs in `entity_ids`), and ``arc_side`` (2E,);
    computed once per run and keys."""

    def build():
        agents = entity_ids(ctx)[1]
        senders, receivers = ctx.arcs.src, ctx.arcs.dst
        if agents.shape[0]:
            senders, receivers = agents[senders], agents[receivers]
        edge_keys = link_keys(keys[:, None], senders[0::2], receivers[0::2])  # arcs 2e and 2e + 1: edge e's
        return dict(edge_keys=frozen(edge_keys, np.uint64), arc_side=frozen(arc_side(senders, receivers), np.uint8))

    return per_run(ctx, f"link keys {keys.tobytes().hex()}", build)


def _no_keys(B: int) -> dict:
    """The `Sampler`'s link keys where the kernels draw no links."""
    return dict(edge_keys=frozen(np.zeros((B, 0)), np.uint64), arc_side=frozen(np.zeros(0), np.uint8))


def _model(tables, problem, markov: bool, rewards=None) -> dict:
    """The `Sampler`'s model fields (read-only): d's and the transitions' alias tables, the restarts' terminal flags,
    the reward table (``rewards``: its rows of a rank's agents), sigma and the noise; a source without a model (a
    simulator's or a data file's samples) leaves them unread."""
    if tables is None:
        empty_f, empty_i = np.zeros((1, 1)), np.zeros((1, 1), np.int64)
        arrays = (empty_f[0], empty_i[0], empty_f, empty_i, np.zeros(0, np.bool_), np.zeros((1, 1, 1, 1)))
        sigma, noise = 1.0, 0
    else:
        rewards = problem.reward_table if rewards is None else rewards
        arrays = (
            tables.d_prob,
            tables.d_alias,
            tables.sa_prob,
            tables.sa_alias,
            restart_flags(problem, markov),
            rewards,
        )
        sigma, noise = float(problem.sigma), NOISE_CODES[problem.reward_noise]
    dtypes = (np.float64, np.int64, np.float64, np.int64, np.bool_, np.float64)
    names = ("d_prob", "d_alias", "sa_prob", "sa_alias", "terminal", "rewards")
    return {name: frozen(x, dtype) for name, x, dtype in zip(names, arrays, dtypes)} | dict(sigma=sigma, noise=noise)


def _no_loss(B: int) -> dict:
    """The `Sampler`'s channel fields where the kernels draw no losses."""
    return dict(loss=frozen(np.zeros((0, 0)), np.float64), links=np.zeros((B, 0), np.uint8))


def _ids(ids: tuple) -> dict:
    """`entity_ids` as the `Sampler`'s fields."""
    return dict(zip(("obs_ids", "agent_ids", "counted", "purpose"), ids))


def entity_ids(ctx) -> tuple:
    """(each observation's and each row's agent in the whole network, 1 for each arc the counts count, the states'
    purpose: `dgtd.streams`; a link's draws are keyed by its agents, `link_keys_of`): none for a whole network (each
    index is its id, every arc counts), a rank's share's where it is one (`dgtd.backends.share`)."""

    def whole():  # no ids: each entity's index is its id, and every arc counts
        none = np.zeros(0, np.int64)
        shared = ctx.sampling.shared or ctx.network.n_nodes == 1  # one observation: the trajectory every agent sees
        return entities(none, none, none, shared)

    return getattr(ctx, "entity_ids", None) or per_run(ctx, "entity_ids", whole)


def entities(obs_ids, agent_ids, counted, shared: bool) -> tuple:
    """`entity_ids` as the kernels take them."""
    ids = (obs_ids, agent_ids)
    return (*(frozen(x, np.int64) for x in ids), frozen(counted, np.uint8), SHARED_STATE if shared else AGENT_STATE)


def channel_cursor(channel, rng: np.ndarray, fused: bool) -> np.ndarray:
    """The keys and step (B, 2) a kernel draws a channel's events with: the channel's own, which are the samples'
    where the kernel draws those too (one run, one seed's key, one step count)."""
    cursor = np.stack([channel.keys, channel.step.astype(np.uint64)], axis=1)
    if fused and not np.array_equal(cursor, rng):
        raise RuntimeError(f"the channel's keys and step {cursor[:1]} are not the samples' {rng[:1]}")
    return np.ascontiguousarray(cursor)


def restart_flags(problem, markov: bool) -> np.ndarray:
    """The terminal flags (S,) a Markovian sampler reads where an episodic task's restarts are not samples
    (`Problem.restarts`), else none (an i.i.d. sampler skips them through d's tables alone)."""
    flags = problem.skipped_terminals
    return np.ascontiguousarray(flags, np.bool_) if markov and flags is not None else np.zeros(0, np.bool_)


def frozen(x, dtype) -> np.ndarray:
    """A C-contiguous read-only view of ``x`` as ``dtype``."""
    view = np.ascontiguousarray(x, dtype).view()
    view.setflags(write=False)
    return view


def writable(x, dtype) -> np.ndarray:
    """``x`` as a writable C-contiguous array of ``dtype`` (a copy only where it is read-only or of another type)."""
    x = np.ascontiguousarray(x, dtype)
    return x if x.flags.writeable else x.copy()
