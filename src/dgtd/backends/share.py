"""A rank's share of a run as a run of its own, for the compiled driver: its agents and their neighbours as rows, the
links of its agents (and, for Metropolis weights, of its ghosts) as edges, the channel and the problem cut to them.

The compiled driver (`dgtd.backends.compiled.driver`) runs it as it runs a whole network, drawing every number by
the entity's id in the whole network (``agent_ids``; a link by the agents it joins: `dgtd.streams`), so that a
rank's samples and events are the whole run's, and counting only the arcs into the rank's own agents (``counted``).
Its rows are its own agents, its ghosts and, with a halo, the ghosts' other neighbours, in the order of the whole
run's storage rows (`dgtd.backends.compiled.graph.storage_order`), and stored so: each agent's neighbours then come
in the whole run's order, and its sums add in the same order, bit for bit. A local edge keeps its ends' order in the
whole network (the arcs 2e and 2e + 1 of local edge e are the arcs 2g and 2g + 1 of its edge g there), even where
that puts the larger row first.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import numpy as np

from dgtd.backends.compiled.sampling import entities
from dgtd.channels import Arcs
from dgtd.graphs.random import RandomEdges
from dgtd.graphs.topologies import Graph


class _Rows:
    """The problem as the share's rows see it: agent r of the share is agent ``rows[r]`` of the whole problem (an
    estimated one, of a simulator or a recording, has no rewards to draw: its blocks bring them)."""

    def __init__(self, problem, rows: np.ndarray):
        self._problem, self._rows = problem, rows
        table, R = getattr(problem, "reward_table", None), getattr(problem, "R_sample", None)
        self.reward_table = None if table is None else np.ascontiguousarray(table[rows])
        self.R_sample = None if R is None else R[rows]
        self.n_agents = len(rows)

    def __getattr__(self, name: str):
        return getattr(self._problem, name)


@dataclass(frozen=True, eq=False)
class Share:
    """A rank's run: ``ctx`` (a run context over its rows), ``rows`` (each row's agent in the whole network),
    ``edges`` (each local edge's id there) and ``arc_ids`` (each local arc's), ``local_rows`` (the rows of the
    agents ``own`` then ``ghosts`` it was made of) and ``counted`` (1 for the arcs into its own agents: what the rank
    counts and reports)."""

    ctx: Any
    rows: np.ndarray
    edges: np.ndarray
    arc_ids: np.ndarray
    local_rows: np.ndarray
    counted: np.ndarray

    @classmethod
    def of(cls, ctx, own: np.ndarray, ghosts: np.ndarray, edges: np.ndarray, position: np.ndarray) -> Share:
        """The share of the agents ``own`` with neighbours ``ghosts`` over the edges ``edges`` (sorted ids), its rows
        in the order of ``position`` (each agent's storage row in the whole run)."""
        ends = ctx.network.base.edges[edges]
        local = np.concatenate([own, ghosts])
        rows = np.union1d(local, ends.ravel())
        rows = rows[np.argsort(position[rows], kind="stable")]
        row = np.full(ctx.network.n_nodes, -1, np.int64)
        row[rows] = np.arange(len(rows))
        graph = Graph(len(rows), row[ends].reshape(-1, 2), name=ctx.network.base.name)
        p = getattr(ctx.network, "p", None)  # a simulator's links (proximity) come with its blocks: no probabilities
        network = RandomEdges(graph, np.ones(len(edges)) if p is None else p[edges])
        arcs = Arcs.of(graph.edges, len(rows))
        arc_ids = (2 * edges[:, None] + np.arange(2)).ravel()
        is_own = np.zeros(len(rows), bool)
        is_own[row[own]] = True
        counted = is_own[arcs.dst].astype(np.uint8)
        problem = _Rows(ctx.problem, rows)
        shared = ctx.sampling.shared or ctx.network.n_nodes == 1
        share = SimpleNamespace(
            problem=problem,
            network=network,
            algorithm=ctx.algorithm,
            sampling=ctx.sampling,
            tables=ctx.tables,
            arcs=arcs,
            tail_start=ctx.tail_start,
            channel=ctx.channel.share(arc_ids, rows),  # each arc's and agent's own links
            Phi=ctx.Phi,
            gamma=ctx.gamma,
            ratio=ctx.ratio,
            R_sample=problem.R_sample,
            continuing=ctx.continuing,
            sigma=ctx.sigma,
            reward_noise=ctx.reward_noise,
            n_states=ctx.n_states,
            n_agents=len(rows),
            # the kernels' numbers of each row and edge (`dgtd.backends.compiled.sampling.entity_ids`) ...
            entity_ids=entities(np.zeros(1, np.int64) if shared else rows, rows, counted, shared),
            # ... and the rows kept in this order (no reordering of its own: `storage_order`)
            _numba_cache={"order": None},
        )
        return cls(share, rows, edges, arc_ids, row[local], counted)
