"""A rank's share as a run of its own (`dgtd.backends.share`) and the compiled driver advanced a step at a time
(`dgtd.backends.compiled.driver.Advance`): the numbers of the whole run, bit for bit, where nothing crosses ranks."""

import numpy as np
import pytest
from numpy.testing import assert_array_equal

import dgtd
from dgtd.algorithms import make_algorithm
from dgtd.backends.compiled.driver import Advance, run_block
from dgtd.backends.share import Share
from dgtd.channels import Lossy
from dgtd.graphs import topologies
from dgtd.graphs.random import random_edges
from dgtd.run.loop import RunSettings, prepare
from dgtd.sources.model import ModelSource, Sampling

T, B = 120, 2


def _setup(name: str, sampling: Sampling):
    sc = dgtd.scenario("paper-example-1")
    network = random_edges(topologies.ring(5), 0.7)
    problem = sc.problem
    channel = Lossy(np.linspace(0.1, 0.5, 10), burst=2.0)
    alg = make_algorithm(name, alpha0=0.5, beta=100.0)
    ctx, *_ = prepare(problem, network, alg, sampling, RunSettings(iterations=T, seeds=B), channel)
    return ctx


def _source(ctx, sampling, rows=None, edges=None):
    source = ModelSource(ctx.problem, ctx.network, sampling, ctx.tables, 3, range(B), "numba")
    if rows is not None:
        source.restrict(rows, edges)
    source.start()
    return source


@pytest.mark.parametrize("name", ["dgtd", "consensus-td0"])
@pytest.mark.parametrize("sampling", [Sampling(), Sampling("markov")], ids=["iid", "markov"])
def test_a_share_of_every_agent_advanced_step_by_step_is_the_whole_run(name, sampling):
    """The share's ids (each row's agent and each edge in the whole network, listed rather than implied), its
    channel state, and one step at a time: the whole run's state, counts and links."""
    ctx = _setup(name, sampling)
    N, q = ctx.network.n_nodes, ctx.problem.n_features
    state = ctx.algorithm.init(B, N, q)._replace(w=np.full((B, N, q), 0.5))
    channel = ctx.channel.init(B, ctx.arcs, 3)
    alphas = 0.5 / np.sqrt(np.arange(T) + 100.0)
    whole, whole_channel, whole_sums = run_block(
        ctx, state, channel, np.zeros((B, N, q)), alphas, _source(ctx, sampling).draws(T)
    )
    order = np.array([3, 0, 4, 1, 2])  # own agents given in any order: the share keeps the whole run's
    share = Share.of(ctx, order[:3], order[3:], np.arange(ctx.network.n_edges), np.arange(N))
    assert_array_equal(share.rows, np.arange(N))
    run = Advance(
        share.ctx,
        state,
        channel,  # over every arc: the share's arcs are the whole network's
        np.zeros((B, N, q)),
        alphas,
        _source(ctx, sampling, share.rows, share.edges).draws(T),
    )
    for t in range(T):
        run.advance(t + 1)
    new, new_channel, sums = run.finish()
    for a, b in zip(whole, new):
        assert_array_equal(a, b)
    assert_array_equal(whole_sums, sums)
    assert_array_equal(whole_channel.links, new_channel.links)
    counted = share.counted.astype(bool)
    assert counted.sum() == 3 * 2  # the arcs into agents 3, 0 and 4 of the ring
    assert np.all(new_channel.messages <= whole_channel.messages) and np.all(new_channel.messages > 0)
