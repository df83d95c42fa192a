"""The directed links of an undirected graph: the two arcs of each edge, and sums over the arcs into each agent."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from dgtd.samples import namespace
from dgtd.streams import arc_side, link_keys, uniforms


@dataclass(frozen=True, eq=False)
class Arcs:
    """Edge e = {u, v} (u < v) of a graph's edge list carries arc 2e from v to u and arc 2e + 1 from u to v.

    ``src`` and ``dst`` (2E,) are each arc's sender and receiver; numbered this way, the arcs into an agent come in
    the order of its edges, so that a sum over them (`into`) adds an edge's terms in the order of the edge list.

    A share of a network's arcs (an MPI rank's: the arcs into its agents, over its own and its neighbours' rows) says
    what each is in the whole network, so that every number drawn for it is the one the whole network draws
    (`dgtd.streams`): ``ids`` each arc's id there, ``agents`` each row's agent, and ``edges`` the column of a step's
    edges up (B, E') that tells whether its link is up. None: the arcs are the whole network's (ids 0 .. 2E - 1, agent
    i in row i, arc a's edge a // 2).
    """

    n_agents: int
    src: np.ndarray
    dst: np.ndarray
    ids: np.ndarray | None = None
    agents: np.ndarray | None = None
    edges: np.ndarray | None = None

    @classmethod
    def of(cls, edges: np.ndarray, n_agents: int) -> Arcs:
        edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
        return cls(int(n_agents), edges[:, ::-1].ravel(), edges.ravel())

    @property
    def n_arcs(self) -> int:
        return self.src.shape[0]

    @property
    def dense(self) -> bool:
        """Whether the graph is dense: N^2 <= 4 x its arcs (mean degree N / 4 and more), where a dense N x N mix
        costs less than sums over the arcs, and an agent's neighbours are nearly every agent."""
        return self.n_agents * self.n_agents <= 4 * self.n_arcs

    @property
    def arc_ids(self) -> np.ndarray:
        """Each arc's id in the whole network (2E,)."""
        return np.arange(self.n_arcs) if self.ids is None else self.ids

    @property
    def agent_ids(self) -> np.ndarray:
        """Each row's agent in the whole network (N,)."""
        return np.arange(self.n_agents) if self.agents is None else self.agents

    @cached_property
    def ends(self) -> tuple[np.ndarray, np.ndarray]:
        """Each arc's sender and receiver in the whole network ((2E,) each): the agents its link joins."""
        agents = self.agent_ids
        return agents[self.src], agents[self.dst]

    @cached_property
    def side(self) -> np.ndarray:
        """Each arc's side of its link (2E,): 0 into the smaller id, 1 into the larger (`dgtd.streams.arc_side`)."""
        return arc_side(*self.ends)

    def link_keys(self, keys: np.ndarray) -> np.ndarray:
        """Each arc's link's key (B, 2E) under seeds' keys (B,), the key of the agents it joins
        (`dgtd.streams.link_keys`), kept for the last keys asked (a run asks with the same ones at every step)."""
        keys = np.asarray(keys, dtype=np.uint64).reshape(-1)
        kept = self.__dict__.get("_link_keys")
        if kept is None or not np.array_equal(kept[0], keys):
            kept = (keys.copy(), link_keys(keys[:, None], *self.ends))
            self.__dict__["_link_keys"] = kept
        return kept[1]

    def uniforms(self, keys: np.ndarray, purpose: int, step: int) -> np.ndarray:
        """One uniform per arc (B, 2E) for ``purpose`` at ``step``: its link's call's u0 for the arc into the smaller
        id, u1 for the other, so that either end draws both of its link's arcs' numbers (`dgtd.streams`)."""
        u0, u1 = uniforms(self.link_keys(keys), purpose, step, 0)
        return np.where(self.side == 0, u0, u1)

    def of_arcs(self, x: np.ndarray) -> np.ndarray:
        """A quantity of every arc of the whole network (2E,) for these arcs."""
        return x if self.ids is None else x[self.ids]

    def of_agents(self, x: np.ndarray) -> np.ndarray:
        """A quantity of every agent of the whole network (N,) for these rows."""
        return x if self.agents is None else x[self.agents]

    def up(self, up: np.ndarray | None, B: int) -> np.ndarray:
        """Arcs up (B, 2E) from a step's edges up (B, E'; None: every edge)."""
        if up is None:
            return np.ones((B, self.n_arcs), bool)
        return self.both_ways(up) if self.edges is None else np.asarray(up)[:, self.edges]

    @staticmethod
    def both_ways(up: np.ndarray) -> np.ndarray:
        """Arcs up (..., 2E) from edges up (..., E): each edge's two arcs are up with it."""
        return np.repeat(np.asarray(up), 2, axis=-1)

    @cached_property
    def _incidence(self):
        """(N, 2E) sparse: 1 at (dst[a], a), so that ``_incidence @ x`` sums each arc's value into its receiver."""
        from scipy.sparse import csr_matrix

        A = self.n_arcs
        return csr_matrix((np.ones(A), (self.dst, np.arange(A))), shape=(self.n_agents, A))

    def into(self, x):
        """sum over the arcs into each agent of x (B, 2E, q) -> (B, N, q); a JAX array's by JAX's segment sum, each
        agent's arcs added in their order too."""
        B, A, q = x.shape
        if A == 0:
            return namespace(x).zeros((B, self.n_agents, q))
        if namespace(x) is not np:
            from jax.ops import segment_sum

            return segment_sum(x.transpose(1, 0, 2), self.dst, self.n_agents).transpose(1, 0, 2)
        out = self._incidence @ x.transpose(1, 0, 2).reshape(A, B * q)
        return np.ascontiguousarray(np.asarray(out).reshape(self.n_agents, B, q).transpose(1, 0, 2))
