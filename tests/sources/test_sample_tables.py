"""Blocks that carry their own rows (`SampleTable`: a simulator's or a data file's samples) run through every kernel
exactly as the model's state indices do."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from dgtd.algorithms import ALGORITHMS, make_algorithm
from dgtd.graphs import topologies
from dgtd.graphs.random import random_edges
from dgtd.problems import exact, tasks
from dgtd.run.loop import RunSettings, run
from dgtd.samples import Block, SampleTable
from dgtd.sources.model import ModelSource, SamplerTables, Sampling


class Tabled:
    """A model source whose blocks carry one row per sample (s and s' each their own), as a simulator's do."""

    def __init__(self, problem, network, sampling, seed, seed_ids):
        tables = SamplerTables.build(problem, exact.Moments(problem).d)
        self.inner = ModelSource(problem, network, sampling, tables, seed, seed_ids)
        self.problem = problem

    def start(self):
        self.inner.start()

    def next_block(self, T):
        blk = self.inner.next_block(T)
        p, n = self.problem, blk.s.size
        s, a, sn = blk.s.ravel(), blk.a.ravel(), blk.s_next.ravel()
        rows = np.concatenate([s, sn])
        table = SampleTable(p.Phi[rows], np.concatenate([p.ratio[s, a], np.ones(n)])[:, None], p.continuing[rows])
        index = np.arange(n).reshape(blk.s.shape)
        return Block(index, np.zeros_like(index), index + n, blk.r, blk.up, table)

    def get_state(self):
        return self.inner.get_state()

    def set_state(self, state):
        self.inner.set_state(state)


@pytest.mark.parametrize("name", sorted(ALGORITHMS))
@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_a_block_with_its_own_rows_gives_the_runs_numbers(name, backend):
    """Off-policy ratios and an episodic task's terminal flags travel in the rows too (Boyan's terminal here)."""
    for problem in (
        tasks.random_mdp(n_agents=4, off_policy=True, seed=2, n_states=6, n_actions=3, n_features=4, gamma=0.9),
        tasks.boyan(n_agents=4, n_states=8),
    ):
        net = random_edges(topologies.ring(4), 0.7)
        alg = make_algorithm(name, alpha0=0.05, beta=10.0)
        settings = RunSettings(iterations=300, seeds=2, seed=4, checkpoints=3, block_size=128, backend=backend)
        ref = run(problem, net, alg, Sampling(), settings)
        got = run(problem, net, alg, Sampling(), settings, source=Tabled(problem, net, Sampling(), 4, range(2)))
        for key in ref.final_state:
            assert_allclose(got.final_state[key], ref.final_state[key], rtol=1e-12, atol=1e-12)
