"""The channel: the NumPy inbox against dense Laplacians, the compiled channel against the NumPy one, and the counts."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit
from numpy.testing import assert_allclose

from dgtd.backends.compiled.channel import Inbox as CompiledInbox
from dgtd.backends.compiled.channel import count_heard, hear, laplacian, metropolis, metropolis_weights, total
from dgtd.backends.compiled.graph import csr_adjacency
from dgtd.channels import Arcs, Perfect
from dgtd.graphs import topologies


def graph_and_links(rng, B=3):
    graph = topologies.ring_with_chords(7, 2)
    return graph, rng.random((B, graph.n_edges)) < 0.5


def test_arcs_carry_each_edge_both_ways():
    arcs = Arcs.of(np.array([[0, 1], [1, 3]]), 4)
    assert arcs.src.tolist() == [1, 0, 3, 1] and arcs.dst.tolist() == [0, 1, 1, 3]
    assert Arcs.both_ways(np.array([[True, False]])).tolist() == [[True, True, False, False]]


def test_the_inbox_aggregates_are_the_laplacians_of_the_links_up(rng):
    """laplacian: L(k) X with L(k) the Laplacian of the edges up; metropolis: L_W(k) X with the Metropolis weights
    1 / (1 + max(d_i, d_j)) on the edges up; total: the adjacency of the edges up times X; count: the degrees."""
    graph, up = graph_and_links(rng)
    X = rng.standard_normal((3, 7, 4))
    inbox = Perfect().inbox(Arcs.of(graph.edges, 7), {"x": X}, up)
    for b in range(3):
        L = graph.laplacian(up[b].astype(float))
        d = np.diag(L)
        u, v = graph.edges.T
        weights = up[b] / (1.0 + np.maximum(d[u], d[v]))
        assert_allclose(inbox.laplacian("x")[b], L @ X[b], atol=1e-12)
        assert_allclose(inbox.metropolis("x")[b], graph.laplacian(weights) @ X[b], atol=1e-12)
        assert_allclose(inbox.total("x")[b], (np.diag(d) - L) @ X[b], atol=1e-12)
        assert_allclose(inbox.count()[b], d)
    every = Perfect().inbox(Arcs.of(graph.edges, 7), {"x": X})
    assert_allclose(every.laplacian("x")[0], graph.laplacian() @ X[0], atol=1e-12)


def test_an_inbox_with_what_arrived_uses_it_and_not_what_was_sent(rng):
    """A channel that changes what arrives (a late or compressed copy) hands ``received``: each arc's value."""
    from dgtd.channels import Inbox

    graph, up = graph_and_links(rng, B=1)
    arcs = Arcs.of(graph.edges, 7)
    X, Y = rng.standard_normal((1, 7, 2)), rng.standard_normal((1, arcs.n_arcs, 2))
    inbox = Inbox(arcs, {"x": X}, Arcs.both_ways(up), received={"x": Y})
    heard = Arcs.both_ways(up)[0]
    want = np.zeros((7, 2))
    for a in np.flatnonzero(heard):
        want[arcs.dst[a]] += X[0, arcs.dst[a]] - Y[0, a]
    assert_allclose(inbox.laplacian("x")[0], want, atol=1e-12)


@njit
def compiled_aggregates(X, up, indptr, nbr, eid, kind):
    """Every agent's aggregate of X through the compiled channel (kind 0: laplacian, 1: metropolis, 2: total)."""
    B, N, q = X.shape
    sent = X.reshape(1, B, N, q)
    out = np.zeros((B, N, q))
    heard, n_heard, weights = np.zeros((1, N), np.int64), np.zeros((1, 8), np.int64), np.zeros((1, N))
    degree, sums = np.zeros((1, N), np.int64), np.zeros((1, 1, q))
    for b in range(B):
        count_heard(up, b, indptr, eid, degree, 0)
        for i in range(N):
            inbox = CompiledInbox(sent, heard, n_heard, weights, degree, 0, sums, 0, np.zeros(0))
            hear(inbox, up, b, indptr, nbr, eid, i)
            metropolis_weights(inbox, i)
            if kind == 0:
                laplacian(inbox, 0, b, i)
            elif kind == 1:
                metropolis(inbox, 0, b, i)
            else:
                total(inbox, 0, b, i)
            out[b, i] = sums[0, 0]
    return out


@pytest.mark.parametrize("kind, name", [(0, "laplacian"), (1, "metropolis"), (2, "total")])
def test_the_compiled_channel_hears_what_the_numpy_one_hears(kind, name, rng):
    """The same aggregates to rounding (each sums the same terms; the compiled Laplacian as d_i x_i - sum_j x_j)."""
    graph, up = graph_and_links(rng)
    X = rng.standard_normal((3, 7, 5))
    want = getattr(Perfect().inbox(Arcs.of(graph.edges, 7), {"x": X}, up), name)("x")
    got = compiled_aggregates(X, up, *csr_adjacency(graph.edges, 7), kind)
    assert_allclose(got, want, rtol=1e-13, atol=1e-13)


def test_the_perfect_channel_counts_every_message_on_every_arc_up(rng):
    """Two messages of 4 numbers on a ring of 5 whose links are up at random: per step, 2 arcs per edge up, each
    carrying both messages, of 64 bits a number."""
    graph, up = topologies.ring(5), rng.random((2, 5)) < 0.5
    arcs, channel = Arcs.of(graph.edges, 5), Perfect()
    sent = {"w": np.zeros((2, 5, 4)), "z": np.zeros((2, 5, 4))}
    _, state = channel.deliver(channel.init(2, arcs), arcs, sent, up)
    _, state = channel.deliver(state, arcs, sent, None)
    assert_allclose(state.messages, 2 * (up.sum(axis=1) + 5) * 2)
    assert_allclose(state.bits, state.messages * 4 * 64)
    from dgtd.channels import counted  # as the compiled driver counts a block's arcs at once

    twin = counted(channel.init(2, arcs), 2 * (up.sum(axis=1) + 5), 2, 8)
    assert np.array_equal(twin.messages, state.messages) and np.array_equal(twin.bits, state.bits)
