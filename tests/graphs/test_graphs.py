"""Topologies, random edge processes, Laplacians and the mean-connectivity check."""

import networkx as nx
import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from dgtd.errors import DgtdInputError
from dgtd.graphs import topologies
from dgtd.graphs.random import random_edges


def test_topology_edge_counts():
    assert topologies.path(5).n_edges == 4
    assert topologies.ring(5).n_edges == 5
    assert topologies.star(5).n_edges == 4
    assert topologies.complete(5).n_edges == 10
    assert_array_equal(topologies.star(3).edges, [[0, 1], [0, 2]])


def test_laplacian_definition():
    # L = H - W for the path 0 - 1 - 2 (paper section 'Graph theory').
    assert_array_equal(topologies.path(3).laplacian(), [[1, -1, 0], [-1, 2, -1], [0, -1, 1]])
    L = topologies.ring_with_chords(8, 3).laplacian()
    assert_allclose(L, L.T)
    assert_allclose(L @ np.ones(8), 0)
    assert np.linalg.eigvalsh(L)[1] > 1e-9  # connected: 0 is a simple eigenvalue


def test_from_edges_normalises_and_checks():
    g = topologies.from_edges(3, [(1, 0), (0, 1), (2, 1)])
    assert_array_equal(g.edges, [[0, 1], [1, 2]])
    with pytest.raises(DgtdInputError, match="self-loops"):
        topologies.from_edges(3, [(1, 1)])
    with pytest.raises(DgtdInputError, match="endpoints"):
        topologies.from_edges(3, [(0, 3)])


def test_from_networkx_relabels_sorted_nodes():
    G = nx.Graph([("b", "c"), ("a", "b")])
    g = topologies.from_networkx(G)
    assert_array_equal(g.edges, [[0, 1], [1, 2]])
    assert topologies.from_networkx(nx.petersen_graph()).n_edges == 15


def test_mean_laplacian_is_p_times_laplacian():
    base = topologies.ring(6)
    p = np.linspace(0.1, 0.9, 6)
    assert_allclose(random_edges(base, p).mean_laplacian(), base.laplacian(p))


def test_mean_laplacian_matches_sampled_average():
    # 20 000 draws: each entry's standard error <= sqrt(0.25 * 4 / 2e4) ~ 0.007, tolerance 0.03.
    net = random_edges(topologies.complete(4), 0.3)
    u = np.random.default_rng(0).random((20_000, net.n_edges))
    masks = net.masks_from_uniforms(u)
    Ls = np.einsum(
        "te,eij->ij", masks.astype(float), np.stack([topologies.from_edges(4, [e]).laplacian() for e in net.base.edges])
    ) / len(u)
    assert_allclose(Ls, net.mean_laplacian(), atol=0.03)


def test_disconnected_mean_graph_refused():
    with pytest.raises(DgtdInputError, match="disconnected"):
        random_edges(topologies.from_edges(4, [(0, 1), (2, 3)]))
    with pytest.raises(DgtdInputError, match="disconnected"):
        random_edges(topologies.ring(4), [1, 1, 0, 0.0])  # only 0-1 and 0-3 ever up: agent 2 is cut off
    random_edges(topologies.ring(4), [1, 1, 1, 0.0])  # edge 2-3 never up, the path 3-0-1-2 remains


def test_edge_probability_range():
    with pytest.raises(DgtdInputError, match="probabilities"):
        random_edges(topologies.ring(4), 1.5)


def test_read_edge_list(tmp_path):
    f = tmp_path / "g.txt"
    f.write_text("# a triangle\n0 1\n1 2\n2 0\n")
    assert topologies.read_edge_list(str(f)).n_edges == 3
    with pytest.raises(DgtdInputError, match="does not exist"):
        topologies.read_edge_list(str(tmp_path / "none.txt"))
    bad = tmp_path / "bad.txt"
    bad.write_text("0 x\n")
    with pytest.raises(DgtdInputError, match="malformed"):
        topologies.read_edge_list(str(bad))
    weighted = tmp_path / "weighted.txt"
    weighted.write_text("0 1\n1 2 0.5\n")  # a third column would be dropped: refused, naming the line
    with pytest.raises(DgtdInputError, match="line 2 .* 3 columns"):
        topologies.read_edge_list(str(weighted))


def test_all_reachable_matches_scipy(rng):
    from scipy.sparse.csgraph import connected_components

    for _ in range(30):
        n = int(rng.integers(1, 12))
        A = rng.random((n, n)) < rng.uniform(0.05, 0.4)
        strong = connected_components(A, directed=True, connection="strong")[0] == 1
        assert (topologies.all_reachable(A) and topologies.all_reachable(A.T)) == strong
        sym = A | A.T
        assert topologies.all_reachable(sym) == (connected_components(sym, directed=False)[0] == 1)
