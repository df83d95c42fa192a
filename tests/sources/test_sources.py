"""Every sample source passes the conformance check (`dgtd.sources.check.check_source`): shapes, each seed's own
stream, blocks that concatenate, resume, links drawn from the run's network, and the model's samples on both
backends; and the check catches a source that breaks a rule."""

from __future__ import annotations

import numpy as np
import pytest

from dgtd.graphs import topologies
from dgtd.graphs.random import random_edges
from dgtd.problems import exact
from dgtd.problems.generators import random_problem
from dgtd.samples import Block
from dgtd.sources.check import check_source
from dgtd.sources.model import ModelSource, SamplerTables, Sampling


@pytest.mark.parametrize("sampling", [Sampling("iid", False), Sampling("markov", True)], ids=["iid", "markov-shared"])
def test_a_model_source_conforms(sampling):
    problem = random_problem(6, 4, 3, np.random.default_rng(1), reward_noise="bernoulli")
    network = random_edges(topologies.ring(4), 0.6)
    tables = SamplerTables.build(problem, exact.Moments(problem).d)

    def source(backend):
        return lambda seed, ids: ModelSource(problem, network, sampling, tables, seed, ids, backend)

    check_source(source("numpy"), network, 4, twin=source("numba"))


@pytest.mark.parametrize("edge_prob", [0.5, 1.0])
def test_recorded_data_conforms_and_draws_its_links_from_the_network(tmp_path, edge_prob):
    from helpers import record

    from dgtd.problems.tasks import garnet
    from dgtd.sources.data import DataSource, TransitionFile

    problem = garnet(n_states=8, branching=3, n_agents=3, n_features=3, seed=1)
    np.savez(tmp_path / "t.npz", **record(problem, seeds=3, steps=500))
    data, network = TransitionFile(tmp_path / "t.npz"), random_edges(topologies.ring(3), edge_prob)
    check_source(lambda seed, ids: DataSource(data, ids, seed, network), network, 3)


def test_a_simulator_conforms():
    from envs.chain import make_chain

    from dgtd.sources.env import EnvSource

    network = random_edges(topologies.ring(3), 0.6)
    features = lambda x: np.eye(4)[np.asarray(x[:, 0], dtype=int)]  # noqa: E731
    check_source(
        lambda seed, ids: EnvSource(make_chain, features, seed, ids, network=network),
        network,
        3,
        steps=300,
        resumable=False,
    )


def test_the_robots_conform():
    from dgtd.graphs.proximity import ProximityNetwork
    from dgtd.scenarios.robots import PatrolSource, PatrolWorld

    world = PatrolWorld()
    network = ProximityNetwork(world.n_robots, 5.0)
    check_source(lambda seed, ids: PatrolSource(world, network, seed, ids), network, world.n_robots, random_links=False)


class AllLinksUp:
    """A model source that forgets the network's links, as runs on recordings did: every edge up at every step."""

    def __init__(self, inner):
        self.inner = inner

    def start(self):
        self.inner.start()

    def next_block(self, T):
        blk = self.inner.next_block(T)
        return blk._replace(up=np.ones_like(blk.up))

    def get_state(self):
        return self.inner.get_state()

    def set_state(self, state):
        self.inner.set_state(state)


class SharedStream(AllLinksUp):
    """A source whose seeds share one stream: seed k's samples depend on how many seeds run beside it."""

    def next_block(self, T):
        blk = self.inner.next_block(T)
        return blk._replace(s=np.roll(blk.s, 1, axis=1))


@pytest.mark.parametrize(
    "broken, words", [(AllLinksUp, "not drawn from the run's network"), (SharedStream, "alone and beside others")]
)
def test_the_check_catches_a_broken_source(broken, words):
    problem = random_problem(6, 4, 3, np.random.default_rng(1))
    network = random_edges(topologies.ring(4), 0.6)
    tables = SamplerTables.build(problem, exact.Moments(problem).d)
    make = lambda seed, ids: broken(ModelSource(problem, network, Sampling(), tables, seed, ids))  # noqa: E731
    with pytest.raises(AssertionError, match=words):
        check_source(make, network, 4)


def test_a_block_without_links_on_a_random_network_is_refused():
    problem = random_problem(6, 4, 3, np.random.default_rng(1))
    network = random_edges(topologies.ring(4), 0.6)
    tables = SamplerTables.build(problem, exact.Moments(problem).d)

    class NoLinks(AllLinksUp):
        def next_block(self, T):
            return Block(*self.inner.next_block(T)[:4], None)

    with pytest.raises(AssertionError, match="no links"):
        check_source(
            lambda seed, ids: NoLinks(ModelSource(problem, network, Sampling(), tables, seed, ids)), network, 4
        )
