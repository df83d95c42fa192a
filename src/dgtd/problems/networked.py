"""Networked MDPs: agents with local states (Qu, Wierman and Li, "Scalable reinforcement learning of localized
policies for multi-agent networked systems", L4DC 2020, section 2).

Agent i has its own state s_i (S of them) and action a_i (A of them); its next state depends on its neighbourhood's
states and its own action only, and its reward on its own state and action:

    P(s' | s, a) = prod_i P_i(s_i' | s_{N_i}, a_i),     r_i(s_i, a_i),     rbar = (1/N) sum_i r_i,

N_i agent i and its neighbours in a graph (agent i first, then its neighbours in ascending order; the
neighbourhood's states indexed in that order, the first the most significant). The team's objective is the average
of the agents' rewards. Each agent's next state is drawn from its own keyed stream (purpose AGENT_STATE, entity i:
`dgtd.streams`), so any set of agents steps alone, given its neighbourhoods' states, to the numbers the whole network
gives; a generated problem draws each agent's tables from streams keyed by its id (`random_networked`), so an agent's
tables are the same in any network where its neighbourhood's size is. For a few agents the joint table is a team MDP
(`NetworkedMDP.joint`), whose exact J, J* and critics `dgtd.problems.team` computes.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dgtd.errors import DgtdInputError
from dgtd.problems import team
from dgtd.streams import AGENT_START, AGENT_STATE, PROBLEM, seed_key, uniforms

JOINT_ENTRIES = 1 << 24  # S^N x A^N x S^N: the largest joint table built (128 MB)


@dataclass(frozen=True)
class NetworkedMDP:
    """``neighbourhoods`` (N, K) each agent's N_i padded with -1 to the largest size K; ``P`` (N, S^K, A, S) each
    agent's P_i(s_i' | s_{N_i}, a_i) over its neighbourhood's S^|N_i| states (rows beyond them unused); ``R`` (N, S,
    A) r_i(s_i, a_i); ``gamma`` the discount of the discounted objective; ``start`` (S,) each agent's first state's
    distribution, the agents independent."""

    neighbourhoods: np.ndarray
    P: np.ndarray
    R: np.ndarray
    gamma: float
    start: np.ndarray
    name: str = "networked"

    def __post_init__(self):
        N, K = self.neighbourhoods.shape
        if N < 1 or K < 1 or (self.neighbourhoods[:, 0] != np.arange(N)).any():
            raise DgtdInputError("a networked MDP's neighbourhoods are one row an agent, the agent itself first")
        S, A = self.R.shape[1], self.R.shape[2]
        if self.R.shape[0] != N or self.P.shape != (N, S**K, A, S):
            raise DgtdInputError(
                f"a networked MDP of {N} agents, {S} local states, {A} actions and neighbourhoods of at most {K} needs "
                f"P (N, S^K, A, S) = {(N, S**K, A, S)} and R (N, S, A) = {(N, S, A)}; got {self.P.shape}, "
                f"{self.R.shape}"
            )
        rows = self.P[np.arange(N)[:, None], np.arange(S**K)[None, :]][self._used()]
        if not (np.isfinite(rows).all() and (rows >= 0).all() and np.allclose(rows.sum(axis=-1), 1.0)):
            raise DgtdInputError("each row P_i(. | s_N_i, a_i) of a networked MDP is a probability distribution")
        if not np.isfinite(self.R).all():
            raise DgtdInputError("a networked MDP's rewards r_i(s_i, a_i) must be finite")
        if not 0.0 <= self.gamma < 1.0:
            raise DgtdInputError(f"gamma must be in [0, 1), got {self.gamma}")
        if self.start.shape != (S,) or not np.isclose(self.start.sum(), 1.0) or (self.start < 0).any():
            raise DgtdInputError(f"start is each agent's first state's distribution, (S,) = ({S},) summing to 1")

    def _used(self) -> np.ndarray:
        """(N, S^K): the rows of each agent's P_i that its neighbourhood's states index."""
        S, K = self.n_states, self.neighbourhoods.shape[1]
        return np.arange(S**K)[None, :] < (S**self.sizes)[:, None]

    @property
    def n_agents(self) -> int:
        return self.neighbourhoods.shape[0]

    @property
    def n_states(self) -> int:
        return self.R.shape[1]

    @property
    def n_actions(self) -> int:
        return self.R.shape[2]

    @property
    def has_joint(self) -> bool:
        """Whether the joint table (S^N x A^N x S^N entries) is small enough to build (`JOINT_ENTRIES`)."""
        N = self.n_agents
        return bool(2 * N * np.log2(self.n_states) + N * np.log2(self.n_actions) <= np.log2(JOINT_ENTRIES))

    @property
    def sizes(self) -> np.ndarray:
        """|N_i| of every agent (N,)."""
        return (self.neighbourhoods >= 0).sum(axis=1)

    @property
    def actions(self) -> np.ndarray:
        """(N,) each agent's action count (every agent A)."""
        return np.full(self.n_agents, self.n_actions)

    @property
    def observations(self) -> int:
        """The rows of an agent's policy: its neighbourhood's states, S^K (the largest neighbourhood's)."""
        return self.n_states ** self.neighbourhoods.shape[1]

    @property
    def state_values(self) -> int:
        return self.n_states

    def first_states(self, keys: np.ndarray, m: int) -> np.ndarray:
        """(B, N) every agent's first state of episode m, each by its own number (AGENT_START, m, agent)."""
        u = uniforms(keys[:, None], AGENT_START, m, np.arange(self.n_agents))[0]
        return team.draw(np.cumsum(self.start)[None, None, :], u)

    def observe(self, s: np.ndarray) -> np.ndarray:
        """(B, N) each agent's policy row: its neighbourhood's states (`local_index`)."""
        return self.local_index(s, np.arange(self.n_agents))

    def local_index(self, s: np.ndarray, agents: np.ndarray) -> np.ndarray:
        """The index of each of ``agents``' neighbourhood states (B, n) in every agent's states ``s`` (B, N)."""
        return hood_index(self.neighbourhoods[agents], s, self.n_states)

    def step(self, s: np.ndarray, a: np.ndarray, keys: np.ndarray, k: int, agents=None) -> tuple:
        """(s' (B, n), r (B, n)) of ``agents`` (default every agent) at step k from every agent's states ``s`` (B, N)
        and the agents' actions ``a`` (B, n): s_i' ~ P_i(. | s_N_i, a_i) by agent i's own number (AGENT_STATE, step
        k, entity i) of seeds ``keys`` (B,), r_i = r_i(s_i, a_i)."""
        agents = np.arange(self.n_agents) if agents is None else np.asarray(agents)
        u = uniforms(keys[:, None], AGENT_STATE, k, agents)[0]
        rows = self.P[agents[None, :], self.local_index(s, agents), a]  # (B, n, S)
        return team.draw(np.cumsum(rows, axis=-1), u), self.R[agents[None, :], s[:, agents], a]

    def joint(self, policies=None) -> team.TeamMDP:
        """The team MDP of the joint table (S^N states, A^N joint actions; each agent's reward over them), for a few
        agents; ``policies`` the agents' local policies pi_i(a_i | s_N_i) (each (S^|N_i|, A)) as its starting ones."""
        N, S, A = self.n_agents, self.n_states, self.n_actions
        if not self.has_joint:
            raise DgtdInputError(
                f"the joint table of {N} agents of {S} states and {A} actions has {S}^{2 * N} x {A}^{N} entries, more "
                f"than {JOINT_ENTRIES:,}: exact answers need fewer agents"
            )
        s = np.stack(np.unravel_index(np.arange(S**N), (S,) * N), axis=-1)  # (S^N, N): every joint state
        a = np.stack(np.unravel_index(np.arange(A**N), (A,) * N), axis=-1)  # (A^N, N)
        here = self.local_index(s, np.arange(N))  # (S^N, N)
        P = np.ones((S**N, A**N, S**N))
        for i in range(N):  # prod_i P_i(s_i' | s_N_i, a_i)
            P *= self.P[i][here[:, i][:, None, None], a[None, :, i][..., None], s[None, None, :, i]]
        R = self.R[np.arange(N)[:, None, None], s.T[:, :, None], a.T[:, None, :]]  # (N, S^N, A^N)
        joint_start = np.prod(self.start[s], axis=1)
        tables = None if policies is None else [np.asarray(p)[here[:, i]] for i, p in enumerate(policies)]
        return team.team_mdp(
            P, R, np.eye(S**N), self.gamma, (A,) * N, start=joint_start, name=f"{self.name}-joint", policies=tables
        )


def hood_index(hoods: np.ndarray, digits: np.ndarray, base: int) -> np.ndarray:
    """(B, n): for each neighbourhood of ``hoods`` (n, K; padded with -1) the number whose base-``base`` digits are
    its members' ``digits`` (B, N: one an agent), the first member the most significant."""
    valid = hoods >= 0
    return mixed_radix(np.where(valid, digits[:, np.maximum(hoods, 0)], 0), valid, base)


def mixed_radix(members: np.ndarray, valid: np.ndarray, base: int) -> np.ndarray:
    """(...): the number whose base-``base`` digits are ``members`` (..., n, K) where ``valid`` (n, K), the first the
    most significant (`hood_index` of digits already gathered)."""
    places = np.maximum(np.cumsum(valid[:, ::-1], axis=1)[:, ::-1] - 1, 0)  # a member's place from the right
    return (np.where(valid, members, 0) * np.where(valid, base**places, 0)).sum(axis=-1)


def neighbourhoods_of(edges: np.ndarray, n_agents: int) -> np.ndarray:
    """(N, K): each agent and its neighbours in ``edges`` (E, 2), ascending after the agent, padded with -1."""
    lists: list[list[int]] = [[] for _ in range(n_agents)]
    for i, j in np.asarray(edges, dtype=np.int64).reshape(-1, 2):
        if i != j:
            lists[i].append(int(j))
            lists[j].append(int(i))
    K = 1 + max((len(set(x)) for x in lists), default=0)
    out = np.full((n_agents, K), -1, dtype=np.int64)
    for i, x in enumerate(lists):
        row = [i, *sorted(set(x))]
        out[i, : len(row)] = row
    return out


def random_networked(
    edges: np.ndarray, n_agents: int, n_states: int = 2, n_actions: int = 2, gamma: float = 0.7, seed: int = 0
) -> NetworkedMDP:
    """A random networked MDP on the graph ``edges``: each row of each P_i uniform on the simplex (Dirichlet(1), as
    normalised exponentials of keyed uniforms) and r_i(s_i, a_i) uniform in [0, 1], agent i's numbers from streams
    keyed by (``seed``, PROBLEM, its id) alone; each agent's first state uniform."""
    if n_agents < 1 or n_states < 1 or n_actions < 1:
        raise DgtdInputError(
            f"a networked MDP needs agents, states and actions >= 1; got {n_agents}, {n_states}, {n_actions}"
        )
    hoods = neighbourhoods_of(edges, n_agents)
    S, A, K = n_states, n_actions, hoods.shape[1]
    key, sizes = seed_key(seed, 0), (hoods >= 0).sum(axis=1)
    P = np.full((n_agents, S**K, A, S), 1.0 / S)  # (rows no neighbourhood state indexes: uniform, unused)
    for m in np.unique(sizes):  # an agent's numbers by its id and its neighbourhood's size alone
        agents = np.flatnonzero(sizes == m)
        u = uniforms(key, PROBLEM, np.arange(S**m * A * S)[None, :], agents[:, None])[0]
        z = -np.log1p(-u).reshape(len(agents), S**m, A, S)  # exponentials: normalised, a Dirichlet(1) row
        P[agents, : S**m] = z / z.sum(axis=-1, keepdims=True)
    R = uniforms(key, PROBLEM, np.arange(S * A)[None, :], np.arange(n_agents)[:, None])[1].reshape(n_agents, S, A)
    return NetworkedMDP(hoods, P, R, gamma, np.full(S, 1.0 / S), "random-networked")


def hops(mdp: NetworkedMDP) -> np.ndarray:
    """(N, N) the graph distance between every two agents (breadth first over the neighbourhoods; N where none)."""
    N = mdp.n_agents
    far = np.full((N, N), N, dtype=np.int64)
    for i in range(N):
        far[i, i], frontier, d = 0, [i], 0
        while frontier:
            d += 1
            reached = {int(j) for k in frontier for j in mdp.neighbourhoods[k] if j >= 0 and far[i, j] == N}
            far[i, sorted(reached)] = d
            frontier = sorted(reached)
    return far


def truncation_errors(mdp: NetworkedMDP, kappas, policies=None) -> np.ndarray:
    """(N, len(kappas)): for each agent i and kappa, max over (s, a) of |Q_i(s, a) - Q_i(s~, a~)|, where (s~, a~)
    keeps the states and actions of the agents within kappa hops of i and sets every other's to 0: how far agent
    i's discounted action values under ``policies`` (local, each (S^|N_i|, A); default uniform) are from a critic
    truncated to its kappa-hop neighbourhood (Qu, Wierman and Li 2020, Lemma: at most rbar gamma^(kappa+1) /
    (1 - gamma), rbar the largest reward, `truncation_bound`). On the joint table (`NetworkedMDP.joint`)."""
    N, S, A, gamma = mdp.n_agents, mdp.n_states, mdp.n_actions, mdp.gamma
    if policies is None:
        policies = [np.full((S ** int(m), A), 1.0 / A) for m in mdp.sizes]
    joint = mdp.joint(policies)
    P_pi, R_pi = joint.chain(list(joint.policies or ()))  # (the local policies over the joint states)
    V = np.linalg.solve(np.eye(S**N) - gamma * P_pi, R_pi.T)  # (S^N, N): every agent's own reward's values
    Q = joint.R + gamma * np.einsum("sat,tn->nsa", joint.P, V)  # (N, S^N, A^N)
    s = np.stack(np.unravel_index(np.arange(S**N), (S,) * N), axis=-1)
    a = np.stack(np.unravel_index(np.arange(A**N), (A,) * N), axis=-1)
    far, out = hops(mdp), np.zeros((N, len(kappas)))
    for i in range(N):
        for c, kappa in enumerate(kappas):
            kept = far[i] <= kappa
            s_ref = np.ravel_multi_index(tuple(np.where(kept, s, 0).T), (S,) * N)
            a_ref = np.ravel_multi_index(tuple(np.where(kept, a, 0).T), (A,) * N)
            out[i, c] = np.abs(Q[i] - Q[i][s_ref[:, None], a_ref[None, :]]).max()
    return out


def truncation_bound(mdp: NetworkedMDP, kappa) -> np.ndarray:
    """rbar gamma^(kappa + 1) / (1 - gamma): Qu, Wierman and Li's bound on `truncation_errors` (rbar the largest
    |r_i|)."""
    rbar = float(np.abs(mdp.R).max())
    return rbar * mdp.gamma ** (np.asarray(kappa, dtype=np.float64) + 1) / (1 - mdp.gamma)


FILE_HELP = (
    "a networked MDP file (.npz) holds edges (E, 2) the graph's agent pairs, R (N, S, A) r_i(s_i, a_i), P (N, S^K, A, "
    "S) P_i(s_i' | s_N_i, a_i) over each agent's neighbourhood states (the agent first, then its neighbours ascending, "
    "the first the most significant; K the largest neighbourhood), gamma, and optionally start (S,)"
)


def load_networked(path) -> NetworkedMDP:
    """The networked MDP of an .npz file (`FILE_HELP`), every array checked with one line that names it."""
    from dgtd.files import read_npz

    fix = f"{FILE_HELP}; see docs/control.md"
    a = read_npz(path, "networked MDP file", fix, required=("edges", "P", "R", "gamma"))
    R, P, edges = np.asarray(a["R"], dtype=np.float64), np.asarray(a["P"], dtype=np.float64), np.asarray(a["edges"])
    if R.ndim != 3:
        raise DgtdInputError(f"networked MDP file {path}: R must be (N, S, A), got shape {R.shape}; {fix}")
    N, S = R.shape[:2]
    if edges.ndim != 2 or edges.shape[1] != 2 or not np.issubdtype(edges.dtype, np.integer):
        raise DgtdInputError(f"networked MDP file {path}: edges must be whole numbers (E, 2), got {edges.shape}; {fix}")
    if edges.size and (edges.min() < 0 or edges.max() >= N):
        raise DgtdInputError(f"networked MDP file {path}: edges name agents 0 .. {N - 1} (R has {N}); got "
                             f"{edges.min()} .. {edges.max()}")  # fmt: skip
    gamma = np.asarray(a["gamma"], dtype=np.float64)
    if gamma.shape != () or not np.isfinite(gamma):
        raise DgtdInputError(f"networked MDP file {path}: gamma must be one number in [0, 1), got {a['gamma']!r}")
    start = np.asarray(a["start"], dtype=np.float64) if "start" in a else np.full(S, 1.0 / S)
    return NetworkedMDP(neighbourhoods_of(edges, N), P, R, float(gamma), start, Path(path).stem)
