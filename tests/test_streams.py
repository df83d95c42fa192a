"""Keyed random streams: Philox-4x32-10's published known answers, the compiled twin equal to the NumPy definition
bit for bit, and every number a function of (seed, purpose, entity, step) alone."""

import numpy as np
import pytest
from numba import njit
from numpy.testing import assert_array_equal

from dgtd.backends.compiled.rng import _philox, keyed_pairs
from dgtd.channels import Arcs, Lossy
from dgtd.graphs import topologies
from dgtd.sources.model import Streams
from dgtd.streams import (
    AGENT_STATE,
    ARC_LOSS,
    EDGE_UP,
    PURPOSES,
    REWARD,
    SHARED_STATE,
    edge_uniforms,
    link_keys,
    philox4x32,
    seed_key,
    seed_keys,
    singles,
    uniforms,
)

# Random123's kat_vectors, the three "philox4x32 10" lines: counter (4 words), key (2 words), expected (4 words).
KNOWN_ANSWERS = [
    ((0, 0, 0, 0), (0, 0), (0x6627E8D5, 0xE169C58D, 0xBC57AC4C, 0x9B00DBD8)),
    ((0xFFFFFFFF,) * 4, (0xFFFFFFFF,) * 2, (0x408F276D, 0x41C83B0E, 0xA20BC7C6, 0x6D5451FD)),
    (
        (0x243F6A88, 0x85A308D3, 0x13198A2E, 0x03707344),
        (0xA4093822, 0x299F31D0),
        (0xD16CFE09, 0x94FDCCEB, 0x5001E420, 0x24126EA1),
    ),
]


@njit
def _compiled_philox(c0, c1, c2, c3, k0, k1):
    return _philox(c0, c1, c2, c3, k0, k1)


@pytest.mark.parametrize("counter, key, expected", KNOWN_ANSWERS)
def test_philox_gives_the_published_known_answers(counter, key, expected):
    words = [np.uint64(x) for x in (*counter, *key)]
    assert [int(x) for x in philox4x32(*words)] == list(expected)
    assert [int(x) for x in _compiled_philox(*words)] == list(expected)
    arrays = [np.full(3, x) for x in words]  # and NumPy's arrays, element by element
    assert [x.tolist() for x in philox4x32(*arrays)] == [[e] * 3 for e in expected]


def test_compiled_twin_equals_the_numpy_definition_on_a_million_keys():
    rng = np.random.default_rng(12)
    n = 1_000_000
    key = rng.integers(0, 2**64 - 1, n, dtype=np.uint64, endpoint=True)
    step = rng.integers(0, 2**64 - 1, n, dtype=np.uint64, endpoint=True)
    step[:1000] = np.arange(1000)  # small steps, as runs have them
    entity = rng.integers(0, 2**32, n, dtype=np.uint64)
    index = rng.integers(0, 2**24, n, dtype=np.uint64)
    for purpose in (SHARED_STATE, ARC_LOSS, 255):
        u0, u1 = uniforms(key, purpose, step, entity, index)
        c0, c1 = np.empty(n), np.empty(n)
        keyed_pairs(key, purpose, step, entity, index, c0, c1)
        assert_array_equal(u0, c0)
        assert_array_equal(u1, c1)
    # doubles in [0, 1) with 53 bits; the mean of 10^6 uniforms has standard deviation 0.29e-3, so 3e-3 is 10 sigma
    both = np.concatenate([u0, u1])
    assert both.min() >= 0.0 and both.max() < 1.0
    assert abs(both.mean() - 0.5) < 3e-3
    assert np.all(both * 2.0**53 == np.floor(both * 2.0**53))


def test_purposes_are_distinct_bytes():
    assert len(set(PURPOSES.values())) == len(PURPOSES)
    assert all(0 <= p < 256 for p in PURPOSES.values())


def test_a_seed_key_depends_on_the_base_seed_and_its_index_only():
    assert_array_equal(seed_keys(5, [3]), seed_keys(5, [0, 1, 2, 3])[3:])
    keys = {seed_key(s, k) for s in range(20) for k in range(20)}
    assert len(keys) == 400
    assert seed_key(2**64 - 1, 2**64 - 1) != seed_key(0, 0)
    with pytest.raises(ValueError, match="2\\^64"):
        seed_key(-1, 0)


def test_the_model_streams_are_the_keyed_numbers():
    """Every uniform of a block is the keyed number of its purpose, entity and step: any agent or rank can draw it."""
    a = Streams(9, [0, 4], 3, 3, [[0, 1], [1, 2]], mode="iid", reward_noise=True, random_edges=True)
    a.draw(5)
    U = a.draw(4)  # steps 5 .. 8
    keys = seed_keys(9, [0, 4])
    for t, k in ((0, 5), (3, 8)):
        for b in range(2):
            for o in range(3):
                s_u, sa_u = uniforms(keys[b], AGENT_STATE, k, o)
                assert (U["state"][t, b, o, 0], U["state"][t, b, o, 1]) == (s_u, sa_u)
                assert U["reward"][t, b, o] == uniforms(keys[b], REWARD, k, o // 2)[o % 2]  # agents in pairs
            for e, (i, j) in enumerate(((0, 1), (1, 2))):  # each edge by the agents it joins
                assert U["edge"][t, b, e] == uniforms(link_keys(keys[b], i, j), EDGE_UP, k, 0)[0]
    shared = Streams(9, [0], 1, 3, [[0, 1], [1, 2]], mode="iid", reward_noise=False, random_edges=False).draw(1)
    assert shared["state"][0, 0, 0, 1] == uniforms(keys[0], SHARED_STATE, 0, 0)[1]
    assert set(shared) == {"state"}


def test_singles_pair_entities_and_any_subset_gives_the_same_numbers():
    keys = seed_keys(3, range(2))[:, None]
    every = singles(keys, EDGE_UP, 17, np.arange(11))
    some = np.array([10, 3, 4, 7])
    assert_array_equal(singles(keys, EDGE_UP, 17, some), every[:, some])
    u0, u1 = uniforms(keys, EDGE_UP, 17, np.arange(6))
    assert_array_equal(every[:, 0::2], u0[:, :6])
    assert_array_equal(every[:, 1::2], u1[:, :5])
    for first, last in ((3, 9), (4, 9), (3, 10), (5, 5)):  # a rank's range of agents, from odd or even ids
        assert_array_equal(singles(keys, EDGE_UP, 17, np.arange(first, last + 1)), every[:, first : last + 1])


def test_both_ends_of_a_link_draw_its_losses_alone():
    """A lossy link's arcs each take the number keyed by its ordered pair of agents and the step: what either end
    computes by itself, wherever the edge is listed."""
    ring = topologies.ring(5)
    arcs = Arcs.of(ring.edges, ring.n_nodes)
    channel = Lossy(np.full(arcs.n_arcs, 0.5))
    state = channel.init(3, arcs, seed=11)
    for _ in range(7):
        kept, _ = channel.arcs_up(state, arcs, None, 3)
        _, state = channel.deliver(state, arcs, {"w": np.zeros((3, 5, 2))}, None)
    assert int(state.step[0]) == 7
    step, keys = 6, seed_keys(11, range(3))
    for b in range(3):
        for a in range(arcs.n_arcs):
            u0, u1 = uniforms(link_keys(keys[b], arcs.src[a], arcs.dst[a]), ARC_LOSS, step, 0)
            u = u0 if arcs.dst[a] < arcs.src[a] else u1  # the arc into the smaller id takes u0
            assert kept[b, a] == (u >= 0.5)


def test_links_are_keyed_by_the_agents_they_join_not_by_their_place():
    """The same edges listed in another order, or a part of them, draw the same numbers (what lets a rank make only
    its part of the graph); two different edges draw different ones."""
    keys = seed_keys(4, range(3))
    edges = np.array([[0, 1], [1, 2], [2, 7], [3, 9], [0, 9]])
    steps = np.arange(5, dtype=np.uint64)[:, None, None]
    every = edge_uniforms(keys, steps, edges)
    order = np.array([4, 2, 0, 3, 1])
    assert_array_equal(edge_uniforms(keys, steps, edges[order]), every[:, :, order])
    assert_array_equal(edge_uniforms(keys, steps, edges[order][:, ::-1]), every[:, :, order])  # either end first
    assert_array_equal(edge_uniforms(keys, steps, edges[[3]]), every[:, :, [3]])
    assert len(np.unique(every)) == every.size
    assert link_keys(keys[0], 2, 7) == link_keys(keys[0], 7, 2) != link_keys(keys[0], 2, 8)
    assert link_keys(keys[0], 2, 7) == link_keys(keys[:1, None], np.array([2]), np.array([7]))[0, 0]
    many = link_keys(keys[:, None], np.arange(1000) % 40, np.arange(1000) // 40 + 40)  # 3 000 distinct links
    assert len(np.unique(many)) == many.size
