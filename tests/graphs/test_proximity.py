"""Proximity networks: links from positions (inclusive radius), connectivity, link statistics and the mean graph."""

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from scipy.sparse.csgraph import connected_components

from dgtd.errors import DgtdInputError
from dgtd.graphs.proximity import ProximityNetwork, count_links, empty_stats, is_connected, proximity_masks
from dgtd.graphs.topologies import complete


def edges_up(net: ProximityNetwork, positions) -> set:
    m = net.masks(np.asarray(positions, dtype=float))
    return {tuple(int(v) for v in e) for e in net.base.edges[m]}


def test_hand_placed_positions_give_exactly_the_expected_edges():
    # 0-1 is a 3-4-5 triangle (distance exactly 5: linked, the radius is inclusive); 1-2 is 5 apart along x;
    # 0-4 is 5.000001 apart (not linked); 1-4 is sqrt(10); agent 3 is far from everyone.
    pos = [(0.0, 0.0), (3.0, 4.0), (8.0, 4.0), (20.0, 20.0), (0.0, 5.000001)]
    net = ProximityNetwork(5, 5.0)
    assert edges_up(net, pos) == {(0, 1), (1, 2), (1, 4)}


def test_radius_is_inclusive_and_zero_radius_links_only_coincident_agents():
    assert edges_up(ProximityNetwork(2, 2.0), [(1.0, 1.0), (3.0, 1.0)]) == {(0, 1)}
    assert edges_up(ProximityNetwork(2, 1.999999), [(1.0, 1.0), (3.0, 1.0)]) == set()
    assert edges_up(ProximityNetwork(3, 0.0), [(1.0, 1.0), (1.0, 1.0), (1.0, 1.5)]) == {(0, 1)}


def test_masks_follow_the_complete_graphs_edge_order_and_any_leading_axes():
    rng = np.random.default_rng(0)
    X = rng.random((7, 3, 4, 2)) * 10  # (time, seeds, agents, dim)
    net = ProximityNetwork(4, 4.0)
    assert_array_equal(net.base.edges, complete(4).edges)
    M = net.masks(X)
    assert M.shape == (7, 3, 6)
    for t, b in [(0, 0), (3, 2), (6, 1)]:
        d = np.linalg.norm(X[t, b, :, None] - X[t, b, None, :], axis=-1)
        assert_array_equal(M[t, b], d[net.base.edges[:, 0], net.base.edges[:, 1]] <= 4.0)


def test_three_dimensional_positions_work_too():
    assert proximity_masks(np.array([[0, 0, 0], [1, 2, 2], [1, 2, 5]], float), complete(3).edges, 3.0).tolist() == [
        True,
        False,
        True,
    ]


def test_is_connected_on_hand_cases():
    e = complete(3).edges  # (0,1), (0,2), (1,2)
    assert is_connected(np.array([[1, 0, 1], [1, 0, 0], [0, 0, 0], [1, 1, 1]], bool), e, 3).tolist() == [
        True,
        False,
        False,
        True,
    ]
    assert is_connected(np.zeros((2, 0), bool), np.zeros((0, 2), np.int64), 1).tolist() == [True, True]
    assert is_connected(np.array([[True], [False]]), complete(2).edges, 2).tolist() == [True, False]


def test_is_connected_agrees_with_scipy_on_random_graphs():
    rng = np.random.default_rng(1)
    for N in (4, 7, 12):
        e = complete(N).edges
        masks = rng.random((300, e.shape[0])) < rng.uniform(0.05, 0.4)
        expected = []
        for m in masks:
            A = np.zeros((N, N), bool)
            A[e[m, 0], e[m, 1]] = True
            expected.append(connected_components(A, directed=False)[0] == 1)
        assert_array_equal(is_connected(masks, e, N), expected)


def test_link_statistics_count_frequencies_and_connected_steps():
    e = complete(3).edges
    masks = np.array([[1, 1, 0], [0, 0, 0], [1, 0, 0], [1, 1, 1]], bool)
    stats = count_links(count_links(empty_stats(3), masks[:2], e, 3), masks[2:], e, 3)
    assert stats.steps == 4
    assert_allclose(stats.link_frequency, [0.75, 0.5, 0.25])
    assert stats.connected_fraction == 0.5
    net = stats.mean_network(complete(3))
    assert_allclose(net.p, [0.75, 0.5, 0.25])
    assert_allclose(net.mean_laplacian(), complete(3).laplacian([0.75, 0.5, 0.25]))


def test_a_mean_graph_with_an_agent_never_linked_is_refused():
    e = complete(3).edges
    stats = count_links(empty_stats(3), np.array([[1, 0, 0]] * 5, bool), e, 3)  # agent 2 never linked
    with pytest.raises(DgtdInputError, match="disconnected"):
        stats.mean_network(complete(3))


def test_bad_radius_or_size_is_refused():
    with pytest.raises(DgtdInputError, match="radius"):
        ProximityNetwork(3, -1.0)
    with pytest.raises(DgtdInputError, match="at least one"):
        ProximityNetwork(0, 1.0)


@pytest.mark.parametrize("N", [4, 9])  # 6 edges (masks read as integers) and 36 edges (tested one by one)
def test_count_links_counts_connected_steps_like_is_connected(N):
    rng = np.random.default_rng(N)
    e = complete(N).edges
    masks = rng.random((50, 4, e.shape[0])) < 0.3
    stats = count_links(empty_stats(e.shape[0]), masks, e, N)
    assert stats.connected == int(is_connected(masks, e, N).sum())
    assert_array_equal(stats.up, masks.reshape(-1, e.shape[0]).sum(axis=0))
