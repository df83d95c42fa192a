"""Sampling streams: every random quantity is a transform of uniforms drawn from the seed's keyed streams.

Each uniform is a pure function of (seed, purpose, entity, step) (`dgtd.streams`): the states of observation o at
step k (one pair: u for s ~ d or a restart's state, u for (a, s')), agent i's reward noise at step k, edge e being up
at step k. So a block of T steps is the concatenation of T single steps, seed k's numbers do not depend on how many
seeds ran, and anyone (a kernel, a thread, a rank that holds some agents) can draw exactly the numbers it needs.
Every backend turns the same uniforms into samples with the same arithmetic (`alias_pick`), so the NumPy reference
and the compiled kernels see identical samples.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dgtd.errors import DgtdInputError
from dgtd.fields import option
from dgtd.problems.model import Problem
from dgtd.samples import Block, Draws
from dgtd.streams import (
    AGENT_START,
    AGENT_STATE,
    EDGE_UP,
    REWARD,
    SHARED_START,
    SHARED_STATE,
    link_keys,
    seed_keys,
    singles,
    uniforms,
)

SAMPLING_MODES = ("iid", "markov")


@dataclass(frozen=True)
class Sampling:
    """How the agents see the chain.

    - ``mode``: 'iid' draws s ~ d afresh at every step, as Algorithm 1 states; 'markov' follows trajectories.
    - ``shared``: True is the paper's scenario 1 (all agents observe one state trajectory, each its own
      reward); False is scenario 2 (each agent runs its own independent copy of the chain).
    """

    mode: str = field(default="iid", metadata=option("i.i.d. s ~ d or Markovian trajectories.", flags=("--sampling",)))
    shared: bool = field(
        default=False,
        metadata=option(
            "All agents observe one state trajectory (scenario 1), or each its own copy (scenario 2).",
            flags=("--shared/--independent",),
        ),
    )

    def __post_init__(self):
        if self.mode not in SAMPLING_MODES:
            raise DgtdInputError(f"sampling mode must be one of {', '.join(SAMPLING_MODES)}, got {self.mode!r}")


def alias_table(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Walker/Vose alias tables for each row of p (..., K): one uniform picks an outcome in O(1)."""
    p = np.asarray(p, dtype=np.float64)
    flat = p.reshape(-1, p.shape[-1])
    K = flat.shape[1]
    prob = np.ones_like(flat)
    alias = np.tile(np.arange(K), (flat.shape[0], 1))
    for r, row in enumerate(flat):
        scaled = row / row.sum() * K
        small = [j for j in range(K) if scaled[j] < 1.0]
        large = [j for j in range(K) if scaled[j] >= 1.0]
        while small and large:
            j, big = small.pop(), large.pop()
            prob[r, j] = scaled[j]
            alias[r, j] = big
            scaled[big] -= 1.0 - scaled[j]
            (small if scaled[big] < 1.0 else large).append(big)
        for j in small + large:  # numerical leftovers are certain outcomes
            prob[r, j] = 1.0
    return prob.reshape(p.shape), alias.reshape(p.shape)


def alias_pick(prob: np.ndarray, alias: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Outcome for uniform u in [0, 1): column j = floor(u K), kept if the leftover fraction < prob[j].

    ``prob`` and ``alias`` are (..., K) rows already gathered to u's shape (..., ) plus K.
    """
    K = prob.shape[-1]
    x = u * K
    j = np.minimum(x.astype(np.int64), K - 1)
    frac = x - j
    pj = np.take_along_axis(prob, j[..., None], axis=-1)[..., 0]
    aj = np.take_along_axis(alias, j[..., None], axis=-1)[..., 0]
    return np.where(frac < pj, j, aj)


@dataclass(frozen=True, eq=False)
class SamplerTables:
    """Alias tables of a problem: s ~ d and (a, s') ~ beta(a|s) P(s, a, s') as flat index a * S + s'."""

    d_prob: np.ndarray
    d_alias: np.ndarray
    sa_prob: np.ndarray
    sa_alias: np.ndarray

    @staticmethod
    def build(problem: Problem, d: np.ndarray) -> SamplerTables:
        dp, da = alias_table(d)
        S, A, _ = problem.P_sample.shape
        sp, sa = alias_table(problem.P_sample.reshape(S, A * S))
        return SamplerTables(dp, da, sp, sa)


def reward_from_uniform(mean: np.ndarray, sigma: float, noise: str, u) -> np.ndarray:
    """A reward in [0, sigma] with the given mean: deterministic, sigma * Bernoulli(mean / sigma), or uniform; a
    transition's own reward ('transition') is deterministic given the transition."""
    if noise in ("none", "transition"):
        return mean
    if noise == "bernoulli":
        return np.where(u < mean / sigma, sigma, 0.0)
    h = np.minimum(mean, sigma - mean)
    return mean + h * (2.0 * u - 1.0)


class Streams:
    """The keyed uniform streams of B seeds (`dgtd.streams`); ``draw(T)`` returns the next T steps' uniforms. Their
    whole state is the step they are at: what a checkpoint keeps."""

    def __init__(
        self,
        seed: int,
        seed_ids,
        n_obs: int,
        n_agents: int,
        edges: np.ndarray,
        *,
        mode: str,
        reward_noise: bool,
        random_edges: bool,
        restart_uniform: bool = False,
    ):
        self.seed = int(seed)
        self.width = 2 if mode == "iid" or restart_uniform else 1  # state uniforms per observation and step
        self.seed_ids = np.asarray(seed_ids, dtype=np.int64)
        self.keys = seed_keys(self.seed, self.seed_ids)
        self.pairs = np.asarray(edges, dtype=np.int64).reshape(-1, 2)  # each edge's agents: what its draws are keyed by
        self.n_obs, self.n_agents, self.n_edges = n_obs, n_agents, len(self.pairs)
        self.mode, self.reward_noise, self.random_edges = mode, reward_noise, random_edges
        # one observation is the trajectory every agent sees; else observation o is agent o's own
        self.shared = n_obs == 1
        self.state_purpose = SHARED_STATE if self.shared else AGENT_STATE
        self.obs_ids, self.agent_ids, self.edge_ids = np.arange(n_obs), np.arange(n_agents), np.arange(self.n_edges)
        self.edge_keys = self._edge_keys() if random_edges else None
        self.step = 0

    def restrict(self, agents: np.ndarray, edges: np.ndarray) -> None:
        """Draw only the numbers of ``agents`` and ``edges`` (ids in the whole network): their states (or the shared
        trajectory's), rewards and links, each the number the whole network's streams give it."""
        self.agent_ids, self.edge_ids = np.asarray(agents, np.int64), np.asarray(edges, np.int64)
        if self.edge_keys is not None:
            self.edge_keys = self._edge_keys()
        self.obs_ids = self.obs_ids if self.shared else self.agent_ids
        self.n_obs, self.n_agents, self.n_edges = len(self.obs_ids), len(self.agent_ids), len(self.edge_ids)

    def _edge_keys(self) -> np.ndarray:
        """The keys (B, E) of the links drawn (`dgtd.streams.link_keys`)."""
        pairs = self.pairs[self.edge_ids]
        return link_keys(self.keys[:, None], pairs[:, 0], pairs[:, 1])

    def initial_uniforms(self) -> np.ndarray:
        """Uniforms (B, n_obs) for the initial states s_0 ~ d of Markovian trajectories."""
        start = SHARED_START if self.shared else AGENT_START
        return uniforms(self.keys[:, None], start, 0, self.obs_ids)[0]

    def draw(self, T: int) -> dict[str, np.ndarray]:
        """Next T steps: 'state' (T, B, n_obs, 2 or 1: s ~ d or a skipped restart's state, then (a, s')), 'reward'
        (T, B, N) and 'edge' (T, B, E) when used."""
        steps = (self.step + np.arange(T, dtype=np.uint64))[:, None, None]
        keys = self.keys[None, :, None]
        u_s, u_sa = uniforms(keys, self.state_purpose, steps, self.obs_ids)
        out = {"state": np.stack([u_s, u_sa], axis=-1) if self.width == 2 else u_sa[..., None]}
        if self.reward_noise:
            out["reward"] = singles(keys, REWARD, steps, self.agent_ids)
        if self.edge_keys is not None:  # (random edges: each keyed by its agents)
            out["edge"] = uniforms(self.edge_keys[None], EDGE_UP, steps, 0)[0]
        self.step += T
        return out

    def cursor(self) -> np.ndarray:
        """(B, 2) uint64: each seed's key and the step the streams are at, for kernels that draw the uniforms."""
        return np.stack([self.keys, np.full(self.keys.shape, self.step, np.uint64)], axis=1)

    def get_state(self) -> dict:
        return {"step": self.step}

    def set_state(self, state: dict) -> None:
        self.step = int(state["step"])


def pick_states(tables: SamplerTables, S: int, u_state: np.ndarray, current: np.ndarray | None):
    """(s, a, s') from state uniforms (..., 2 or 1); i.i.d. uses u[..., 0] for s ~ d, else s = current."""
    if current is None:
        K = tables.d_prob.shape[0]
        shape = u_state.shape[:-1]
        s = alias_pick(
            np.broadcast_to(tables.d_prob, shape + (K,)), np.broadcast_to(tables.d_alias, shape + (K,)), u_state[..., 0]
        )
    else:
        s = current
    idx = alias_pick(tables.sa_prob[s], tables.sa_alias[s], u_state[..., -1])
    return s, idx // S, idx % S


def next_current(tables: SamplerTables, S: int, terminal, sn: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Where a Markovian trajectory goes on after (s, a, s'): from s', or, where restarts are not samples
    (``terminal`` given, `Problem.restarts`) and s' is terminal, from the restart's state drawn from u."""
    if terminal is None:
        return sn
    restart = alias_pick(tables.sa_prob[sn], tables.sa_alias[sn], u) % S
    return np.where(terminal[sn], restart, sn)


def rewards(problem: Problem, s: np.ndarray, a: np.ndarray, sn: np.ndarray, u_reward, agents=None) -> np.ndarray:
    """r (..., N): agent i's reward at its observation (s_i, a_i, s'_i); shared observations broadcast. ``agents``:
    the agents (ids) of the observations, where they are not all (an MPI rank's)."""
    agents = np.arange(problem.n_agents) if agents is None else agents
    table = problem.reward_table
    sn = sn if table.shape[3] > 1 else np.zeros_like(sn)
    if s.shape[-1] == len(agents):
        mean = table[agents, s, a, sn]
    else:
        mean = np.moveaxis(table[agents][:, s[..., 0], a[..., 0], sn[..., 0]], 0, -1)
    return reward_from_uniform(mean, problem.sigma, problem.reward_noise, u_reward)


def block_from_uniforms(problem: Problem, network, tables: SamplerTables, U: dict, current, agents=None, edges=None):
    """NumPy reference: turn a block of uniforms into a `Block`; returns (block, current state or None). ``agents``
    and ``edges``: the ids of the agents and edges the uniforms are of, where they are not all (`Streams.restrict`)."""
    S = problem.n_states
    if current is None:
        s, a, sn = pick_states(tables, S, U["state"], None)
    else:
        T = U["state"].shape[0]
        s, a, sn = (np.empty(U["state"].shape[:-1], np.int64) for _ in range(3))
        for t in range(T):
            s[t], a[t], sn[t] = pick_states(tables, S, U["state"][t], current)
            current = next_current(tables, S, problem.skipped_terminals, sn[t], U["state"][t][..., 0])
    r = rewards(problem, s, a, sn, U.get("reward"), agents)
    up = None
    if "edge" in U:
        up = network.masks_from_uniforms(U["edge"]) if edges is None else U["edge"] < network.p[edges]
    return Block(s, a, sn, np.ascontiguousarray(r, dtype=np.float64), up), current


class ModelSource:
    """Samples drawn from the model: per-seed uniform streams turned into blocks by a backend's sampler.

    A simulator (a world with hidden state, positions that set the network) can stand in for this class:
    anything with ``start()``, ``next_block(T) -> Block``, ``get_state()`` and ``set_state()`` will do.
    """

    def __init__(
        self,
        problem: Problem,
        network,
        sampling: Sampling,
        tables: SamplerTables,
        seed: int,
        seed_ids,
        backend: str = "numpy",
    ):
        self.problem, self.network, self.tables = problem, network, tables
        N = problem.n_agents
        self.n_obs = 1 if sampling.shared else N
        self.streams = Streams(
            seed,
            seed_ids,
            self.n_obs,
            N,
            network.base.edges,
            mode=sampling.mode,
            reward_noise=problem.reward_noise not in ("none", "transition"),
            random_edges=not network.fixed,
            restart_uniform=sampling.mode == "markov" and problem.skipped_terminals is not None,
        )
        self.markov = sampling.mode == "markov"
        self.backend = backend
        self.current: np.ndarray | None = None
        self.agents: np.ndarray | None = None  # all of them (`restrict`)
        self.edges: np.ndarray | None = None

    def restrict(self, agents: np.ndarray, edges: np.ndarray) -> None:
        """Draw only the samples of ``agents`` and the links of ``edges`` (ids in the whole network, as an MPI rank
        does for its own agents and their neighbours): a block then holds their rows (T, B, len(agents)) and columns
        (T, B, len(edges)), each the sample the whole network's run gives it (`Streams.restrict`)."""
        self.streams.restrict(agents, edges)
        self.agents, self.edges = self.streams.agent_ids, self.streams.edge_ids
        self.n_obs = self.streams.n_obs
        if self.current is not None and not self.streams.shared:
            self.current = self.current[:, self.agents]

    def start(self) -> None:
        """Initial states s_0 ~ d of Markovian trajectories, from the state streams' first draws."""
        if self.markov:
            u0 = self.streams.initial_uniforms()
            self.current, _, _ = pick_states(self.tables, self.problem.n_states, np.stack([u0, u0], -1), None)

    def next_block(self, T: int) -> Block:
        U = self.streams.draw(T)
        if self.backend == "numba":
            from dgtd.backends.compiled.sampling import block_from_uniforms as fast

            blk, self.current = fast(self.problem, self.network, self.tables, U, self.current, self.agents, self.edges)
        else:
            blk, self.current = block_from_uniforms(
                self.problem, self.network, self.tables, U, self.current, self.agents, self.edges
            )
        return blk

    def draws(self, T: int) -> Draws:
        """The next T steps, to be drawn inside a compiled kernel (see `Draws`)."""
        return Draws(self, int(T))

    def get_state(self) -> dict:
        """The step the streams are at and the state of every trajectory drawn here, with their agents' ids where
        these are some agents' (``agents``: a rank's; `dgtd.run.checkpoint.assemble` picks them by id)."""
        current = None if self.current is None else self.current.copy()
        return {"streams": self.streams.get_state(), "current": current, **self._ids()}

    def _ids(self) -> dict:
        return {} if self.state_agents is None or self.current is None else {"agents": self.state_agents}

    @property
    def state_agents(self) -> np.ndarray | None:
        """The agents whose trajectories' states this source holds, where they are some agents' (a rank's); None:
        every agent's, or the one shared trajectory."""
        return None if self.streams.shared else self.agents

    def set_state(self, state: dict) -> None:
        """Continue from `get_state`'s dict, its trajectories' states those of the agents drawn here."""
        self.streams.set_state(state["streams"])
        self.current = None if state["current"] is None else np.array(state["current"])
