"""Sampling streams: alias tables are exact, streams are block-size independent, rewards have the stated law."""

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from dgtd.graphs import topologies
from dgtd.graphs.random import random_edges
from dgtd.problems import exact
from dgtd.problems.generators import random_problem
from dgtd.sources.model import (
    ModelSource,
    SamplerTables,
    Sampling,
    Streams,
    alias_pick,
    alias_table,
    reward_from_uniform,
)


def alias_distribution(prob, alias):
    """The exact law of alias_pick: column j keeps j with probability prob[j] / K, else gives alias[j]."""
    K = prob.shape[-1]
    out = np.zeros(K)
    for j in range(K):
        out[j] += prob[j] / K
        out[alias[j]] += (1 - prob[j]) / K
    return out


def test_alias_table_is_exact(rng):
    for K in (1, 2, 7, 50):
        p = rng.random(K) ** 3
        p[rng.random(K) < 0.3] = 0.0
        if p.sum() == 0:
            p[0] = 1.0
        p /= p.sum()
        prob, alias = alias_table(p)
        assert_allclose(alias_distribution(prob, alias), p, atol=1e-12)


def test_alias_pick_frequencies(rng):
    # 200 000 draws: each frequency's standard error is below 0.0012, so 0.005 is over 4 standard errors.
    p = np.array([0.1, 0.0, 0.6, 0.3])
    prob, alias = alias_table(p)
    u = np.random.default_rng(0).random(200_000)
    x = alias_pick(np.broadcast_to(prob, (u.size, 4)), np.broadcast_to(alias, (u.size, 4)), u)
    assert_allclose(np.bincount(x, minlength=4) / u.size, p, atol=0.005)


def test_streams_do_not_depend_on_block_size():
    edges = [[0, 1], [1, 2], [2, 3], [0, 3], [0, 2]]
    a = Streams(7, [0, 3], 2, 4, edges, mode="iid", reward_noise=True, random_edges=True)
    b = Streams(7, [0, 3], 2, 4, edges, mode="iid", reward_noise=True, random_edges=True)
    whole = a.draw(12)
    parts = [b.draw(5), b.draw(7)]
    for key in whole:
        assert_array_equal(whole[key], np.concatenate([p[key] for p in parts]))


def test_seed_stream_does_not_depend_on_other_seeds():
    one = Streams(7, [3], 1, 2, [[0, 1]], mode="iid", reward_noise=False, random_edges=True).draw(4)
    many = Streams(7, [0, 1, 2, 3], 1, 2, [[0, 1]], mode="iid", reward_noise=False, random_edges=True).draw(4)
    assert_array_equal(one["state"][:, 0], many["state"][:, 3])
    assert_array_equal(one["edge"][:, 0], many["edge"][:, 3])


@pytest.mark.parametrize("noise", ["bernoulli", "uniform"])
def test_reward_noise_mean_and_support(noise):
    # 400 000 draws of rewards in [0, 2]: the mean's standard error is at most 2 / sqrt(4e5) = 0.0032; 0.015 is > 4.
    u = np.random.default_rng(1).random(400_000)
    for mean in (0.0, 0.3, 1.0, 1.7, 2.0):
        r = reward_from_uniform(np.full(u.shape, mean), 2.0, noise, u)
        assert r.min() >= 0.0 and r.max() <= 2.0
        assert abs(r.mean() - mean) < 0.015


def test_iid_states_follow_d(rng):
    # 20 000 steps x 6 agents = 120 000 samples; frequency standard errors < 0.0015, tolerance 0.007.
    p = random_problem(5, 6, 2, rng)
    d = exact.stationary_distribution(p.P)
    net = random_edges(topologies.ring(6), 0.5)
    src = ModelSource(p, net, Sampling("iid"), SamplerTables.build(p, d), 0, range(1))
    src.start()
    blk = src.next_block(20_000)
    assert_allclose(np.bincount(blk.s.ravel(), minlength=5) / blk.s.size, d, atol=0.007)
    # Next states follow P row by row: check the transition counts out of the most visited state.
    s0 = int(np.argmax(d))
    sel = blk.s == s0
    assert_allclose(np.bincount(blk.s_next[sel], minlength=5) / sel.sum(), p.P[s0], atol=0.02)
    assert abs(blk.up.mean() - 0.5) < 0.01


def test_markov_trajectories_are_chained(rng):
    p = random_problem(4, 2, 2, rng)
    d = exact.stationary_distribution(p.P)
    src = ModelSource(p, random_edges(topologies.path(2)), Sampling("markov"), SamplerTables.build(p, d), 0, range(2))
    src.start()
    a, b = src.next_block(10), src.next_block(10)
    assert_array_equal(a.s[1:], a.s_next[:-1])
    assert_array_equal(b.s[0], a.s_next[-1])
    assert a.up is None
