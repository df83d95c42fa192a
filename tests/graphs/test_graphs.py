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


@pytest.mark.parametrize("lanczos", [True, False])
def test_the_sparse_spectrum_ends_are_the_dense_ones_or_a_bound_below(monkeypatch, lanczos):
    """`spectrum_ends` on a mean Laplacian with unequal link probabilities: its largest eigenvalue is the dense
    eigendecomposition's to 1e-9, its smallest non-zero one too by Lanczos; with no work allowed for Lanczos it is
    Mohar's bound, 4 w_min / (N D) with D at most twice agent 0's eccentricity: positive and at most the true one."""
    from dgtd.graphs import random as graph_random

    if not lanczos:
        monkeypatch.setattr(graph_random, "LANCZOS_WORK", 0.0)
    graph = topologies.ring_with_chords(300, 7)
    net = random_edges(graph, np.linspace(0.3, 1.0, graph.n_edges))
    exact = np.linalg.eigvalsh(net.mean_laplacian())
    largest, smallest, how = graph_random.spectrum_ends(net.mean_laplacian(sparse=True))
    assert_allclose(largest, exact[-1], rtol=1e-9)
    if lanczos:
        assert how == "Lanczos"
        assert_allclose(smallest, exact[1], rtol=1e-7)
    else:
        assert how == "Mohar's bound"
        eccentricity = nx.eccentricity(nx.Graph(net.base.edges.tolist()), 0)
        assert_allclose(smallest, 4 * 0.3 / (300 * 2 * eccentricity), rtol=1e-12)
        assert 0 < smallest <= exact[1]


def test_many_agents_mixing_eigenvalues_are_the_dense_ends_from_the_sparse_matrix(monkeypatch):
    """Beyond DENSE_N agents the first-step rule's mixing eigenvalues come from the sparse mean mixing: the same
    spread of points and smallest non-zero one as the dense eigendecomposition gives, for the Laplacian and for
    Metropolis mixing (DENSE_N lowered to make 400 agents many)."""
    from dgtd.algorithms import make_algorithm, mean_dynamics
    from dgtd.problems import exact

    net = random_edges(topologies.ring_with_chords(400, 9), 0.8)
    for name in ("dgtd", "consensus-td0"):
        dense = mean_dynamics._mixing_eigenvalues(make_algorithm(name).mixing, net)
        monkeypatch.setattr(exact, "DENSE_N", 100)
        sparse = mean_dynamics._mixing_eigenvalues(make_algorithm(name).mixing, net)
        monkeypatch.undo()
        assert len(dense) == len(sparse) == mean_dynamics.SPREAD + 1
        assert_allclose(sparse, dense, rtol=1e-7, atol=1e-12)
