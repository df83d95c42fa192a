"""Sparse random graphs from keyed chunks (`dgtd.graphs.chunked`): the edges touching any contiguous set of agents
are the same whatever the grouping (as ranks would make them: 1, 2, 3 or 8), each family has the law it claims, and
a seed's graph is its own."""

from __future__ import annotations

import numpy as np
import pytest

from dgtd.errors import DgtdInputError
from dgtd.graphs.chunked import ChunkedGraph, edges_touching, whole

GRAPHS = [
    ChunkedGraph("erdos-renyi", 1000, 6.0, block=64),
    ChunkedGraph("erdos-renyi", 130, 129.0, block=50),  # p = 1: every pair
    ChunkedGraph("small-world", 1001, 6, rewire=0.2, block=64),
    ChunkedGraph("geometric", 1000, 6.0),  # 22 x 22 cells: a rank's band of rows mid-row
    ChunkedGraph("geometric", 40, 30.0),  # r > 1 / 2: one cell
]


@pytest.mark.parametrize("g", GRAPHS, ids=lambda g: f"{g.kind}-{g.n_agents}")
@pytest.mark.parametrize("ranks", [1, 2, 3, 8])
def test_each_ranks_edges_are_the_whole_graphs_edges_touching_its_agents(g, ranks):
    """Contiguous blocks of agents as `np.array_split` gives ranks (bounds mid-block): each one's edges are, byte for
    byte, the whole graph's edges with an end among its agents, and together they are the whole graph."""
    edges = whole(g).edges
    bounds = np.linspace(0, g.n_agents, ranks + 1).astype(int)
    union = []
    for lo, hi in zip(bounds[:-1], bounds[1:]):
        mine = edges_touching(g, range(lo, hi))
        touching = edges[((edges >= lo) & (edges < hi)).any(axis=1)]
        assert mine.tobytes() == touching.tobytes()
        union.append(mine)
    assert np.array_equal(np.unique(np.concatenate(union), axis=0), edges)


def test_erdos_renyi_edges_are_every_pair_with_the_same_probability():
    """G(N, p), p = d / (N - 1): the edge count is Binomial(N (N - 1) / 2, p), within 4 standard deviations over
    5 seeds; each pair of blocks gets its share of the pairs (a chi-square over the 120 block pairs of 15 blocks, below
    its 99.9 % point for 119 degrees of freedom, 164)."""
    N, d = 960, 8.0
    pairs, p = N * (N - 1) / 2, d / (N - 1)
    counts = np.zeros((15, 15))
    for seed in range(5):
        edges = whole(ChunkedGraph("erdos-renyi", N, d, seed=seed, block=64)).edges
        assert abs(len(edges) - pairs * p) < 4 * np.sqrt(pairs * p * (1 - p)), len(edges)
        assert (edges[:, 0] < edges[:, 1]).all()
        np.add.at(counts, (edges[:, 0] // 64, edges[:, 1] // 64), 1)
    expected = np.triu(np.full((15, 15), 64 * 64.0)) - np.diag(np.full(15, 64 * 64 - 64 * 63 / 2))
    expected *= 5 * p
    upper = np.triu_indices(15)
    chi2 = ((counts[upper] - expected[upper]) ** 2 / expected[upper]).sum()
    assert chi2 < 164, chi2


def test_a_small_world_graph_is_the_ring_lattice_rewired():
    """rewire 0: exactly the ring lattice (each agent linked to its k / 2 next); rewire 1: every link moved, so about
    k / (N - 1) of them land on the lattice again (within 4 standard deviations); the edges about N k / 2 less the
    few repeats dropped."""
    N, k = 500, 6
    lattice = whole(ChunkedGraph("small-world", N, k, rewire=0.0, block=64)).edges
    expected = {(min(u, (u + j) % N), max(u, (u + j) % N)) for u in range(N) for j in range(1, k // 2 + 1)}
    assert set(map(tuple, lattice.tolist())) == expected
    moved = whole(ChunkedGraph("small-world", N, k, rewire=1.0, block=64)).edges
    assert N * k / 2 - 20 < len(moved) <= N * k / 2
    on_lattice = len(set(map(tuple, moved.tolist())) & expected)
    mean = N * k / 2 * k / (N - 1)
    assert abs(on_lattice - mean) < 4 * np.sqrt(mean), on_lattice


def test_a_geometric_graph_links_the_pairs_within_its_radius_of_uniform_points():
    """The agents numbered cell by cell, each inside its cell; the edges exactly the pairs nearer than r (all pairs
    by brute force); the cells' counts multinomial (a chi-square over the 729 cells below its 99.9 % point); the edge
    count's mean over 5 seeds N d / 2 within 4 standard deviations (the count's variance about its mean, as for
    pairs that are near independently: measured 92^2 over 60 seeds at 8 000, so 1.2 times the mean is taken)."""
    from scipy.spatial.distance import pdist
    from scipy.stats import chi2

    from dgtd.graphs import geometric

    N, d, counts = 2000, 8.0, []
    for seed in range(5):
        g = ChunkedGraph("geometric", N, d, seed=seed)
        G, r = geometric.grid(g), geometric.radius(g)
        assert G == 27 and abs(geometric.mean_degree_at(r, N) - d) < 1e-9
        ids, xy = geometric.points(g, range(G * G))
        assert np.array_equal(ids, np.arange(N))
        cell = (xy[:, 1] * G).astype(int) * G + (xy[:, 0] * G).astype(int)
        assert (np.diff(cell) >= 0).all()
        i, j = np.triu_indices(N, 1)
        near = np.stack([i, j], axis=1)[pdist(xy) < r]
        edges = whole(g).edges
        assert np.array_equal(edges, near)
        in_cells = np.bincount(cell, minlength=G * G)
        assert ((in_cells - N / G**2) ** 2 / (N / G**2)).sum() < chi2.ppf(0.999, G * G - 1)
        counts.append(len(edges))
    assert abs(np.mean(counts) - N * d / 2) < 4 * np.sqrt(1.2 * N * d / 2 / 5), counts


def test_a_seeds_graph_is_its_own():
    for kind in ("erdos-renyi", "geometric"):
        one, again, other = (whole(ChunkedGraph(kind, 300, 5.0, seed=s, block=64)).edges for s in (3, 3, 4))
        assert np.array_equal(one, again) and not np.array_equal(one, other)


@pytest.mark.parametrize(
    "kind, n, d, words",
    [
        ("small-world", 100, 5, "k even"),
        ("erdos-renyi", 100, 0.0, "mean degree"),
        ("erdos-renyi", 1, 1.0, "at least 2 agents"),
        ("lattice", 100, 4, "chunked graphs are"),
    ],
)
def test_a_graph_that_cannot_be_made_is_refused(kind, n, d, words):
    with pytest.raises(DgtdInputError, match=words):
        ChunkedGraph(kind, n, d)


def test_dgtd_run_garnet_on_a_small_world_graph_by_agents(run_cli, tmp_path):
    """`dgtd run garnet --agents N --graph small-world`: the generated task sized by --agents, its agents linked by
    the chunked graph (the header names it), the resolved config recording what made it."""
    import json

    code, out, err = run_cli(
        "run", "garnet", "--agents", 40, "--graph", "small-world", "--mean-degree", 6, "--rewire", 0.2, "-T", 300,
        "--no-progress", "--no-plots", "--out", tmp_path / "g",
    )  # fmt: skip
    assert code == 0, err
    assert len(json.loads((tmp_path / "g" / "summary.json").read_text())["w_last"][0]) == 40  # [seeds][agents]
    edges = whole(ChunkedGraph("small-world", 40, 6, rewire=0.2)).edges
    assert f"small-world on 40 agents, {len(edges)} edges" in out


def test_dgtd_run_garnet_on_a_geometric_graph(run_cli, tmp_path):
    """`--graph geometric --mean-degree d`: the header names the graph and its edges, every agent estimated."""
    import json

    code, out, err = run_cli(
        "run", "garnet", "--agents", 30, "--graph", "geometric", "--mean-degree", 8, "--graph-seed", 2,
        "--no-progress", "--no-plots", "--out", tmp_path / "g",
    )  # fmt: skip
    assert code == 0, err
    g = ChunkedGraph("geometric", 30, 8.0, seed=2)
    assert f"geometric on 30 agents, {len(whole(g).edges)} edges" in out
    summary = json.loads((tmp_path / "g" / "summary.json").read_text())
    assert len(summary["w_last"][0]) == 30


@pytest.mark.parametrize(
    "args, words",
    [
        (["--graph", "ring", "--mean-degree", 4], ["--mean-degree", "small-world, sparse-random or geom", "ring"]),
        (["--graph", "sparse-random", "--rewire", 0.2], ["--rewire", "sparse-random graph has none"]),
        (["--graph", "geometric", "--rewire", 0.2], ["--rewire", "geometric graph has none"]),
        (["--graph", "small-world", "--mean-degree", 3], ["k even"]),
        (["--mean-degree", 4], ["--graph small-world, sparse-random or geometric"]),
    ],
)
def test_a_chunked_graphs_options_where_they_do_not_apply_are_one_line(run_cli, tmp_path, args, words):
    from helpers import one_line_error

    one_line_error(*run_cli("run", "garnet", "--agents", 30, *args, "-T", 10, "--out", tmp_path / "o"), *words)


def test_an_experiment_file_names_a_chunked_graph_as_the_options_do(run_cli, tmp_path):
    """[network] graph = "small-world" with its mean_degree, rewire and graph_seed gives the run the flags give, and
    the resolved config.toml records them so that it runs again to the same numbers."""
    (tmp_path / "exp.toml").write_text(
        '[problem]\nscenario = "garnet"\nparams = { n_agents = 24 }\n[network]\ngraph = "small-world"\n'
        'mean_degree = 4\nrewire = 0.3\ngraph_seed = 3\n[run]\niterations = 200\nbackend = "numpy"\n'
        "[output]\nplots = false\n"
    )
    flags = ["--graph", "small-world", "--mean-degree", 4, "--rewire", 0.3, "--graph-seed", 3]
    common = ["-T", 200, "--backend", "numpy", "--no-plots", "--no-progress"]
    assert run_cli("run", tmp_path / "exp.toml", "--no-progress", "--out", tmp_path / "a")[0] == 0
    assert run_cli("run", "garnet", "--agents", 24, *flags, *common, "--out", tmp_path / "b")[0] == 0
    assert run_cli("run", tmp_path / "a" / "config.toml", "--no-progress", "--out", tmp_path / "c")[0] == 0
    for other in ("b", "c"):
        assert (tmp_path / other / "metrics.csv").read_bytes() == (tmp_path / "a" / "metrics.csv").read_bytes()


@pytest.mark.parametrize("high", [1, 7, 10**6, 10**12])
def test_the_sorting_uniques_are_numpys(high):
    """`unique_ints` and `unique_edges` (a sort: NumPy 2.4's unique hashes, 17-80 times slower at millions) give
    np.unique's answer."""
    from dgtd.graphs.topologies import unique_edges, unique_ints

    rng = np.random.default_rng(high)
    x = rng.integers(0, high, 5000)
    assert np.array_equal(unique_ints(x), np.unique(x)) and unique_ints(x[:0]).size == 0
    e = rng.integers(0, min(high, 10**6), (5000, 2))
    assert np.array_equal(unique_edges(e, min(high, 10**6)), np.unique(e, axis=0))
