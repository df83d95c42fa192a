"""Whole runs: reproducibility, seed and block-size independence, backend agreement, convergence to w*."""

import dataclasses
import subprocess
import sys

import numpy as np
import pytest
from conftest import cli_env
from helpers import agent_layout_param
from numpy.testing import assert_allclose, assert_array_equal

from dgtd.algorithms import ALGORITHMS
from dgtd.algorithms.dgtd import DGTD
from dgtd.graphs import topologies
from dgtd.graphs.random import random_edges
from dgtd.problems.generators import random_mdp_problem, random_problem
from dgtd.run.loop import RunSettings, run
from dgtd.scenarios import get_scenario
from dgtd.sources.model import Sampling


def small_run(backend="numpy", seeds=2, T=300, block=64, sampling=Sampling(), problem=None, p_edge=0.6, **kw):
    problem = problem or random_problem(5, 4, 3, np.random.default_rng(3), reward_noise=kw.pop("noise", "none"))
    net = random_edges(topologies.ring(problem.n_agents), p_edge)
    alg = DGTD(alpha0=0.5, beta=10, kappa=1.0, **kw)
    return run(
        problem,
        net,
        alg,
        sampling,
        RunSettings(iterations=T, seeds=seeds, seed=11, checkpoints=5, block_size=block, backend=backend),
    )


def test_same_seed_same_numbers():
    a, b = small_run(), small_run()
    assert_array_equal(a.w_last, b.w_last)
    assert_array_equal(a.metrics["error_avg"], b.metrics["error_avg"])


def test_seed_k_does_not_depend_on_number_of_seeds():
    one, three = small_run(seeds=1), small_run(seeds=3)
    assert_array_equal(one.w_last[0], three.w_last[0])
    assert_array_equal(one.w_avg[0], three.w_avg[0])
    two = small_run(seeds=2)
    assert_array_equal(two.w_last[1], three.w_last[1])
    assert not np.array_equal(three.w_last[0], three.w_last[1])


@pytest.mark.parametrize("backend, layout", [("numpy", None), ("numba", "seeds"), ("numba", "agents")])
def test_block_size_does_not_change_results(backend, layout, monkeypatch):
    """Blocks of 7 steps (odd: the double buffers of the messages end a block on their other half, and the agent
    layout's next-step samples must not run past the block) give the numbers of one block."""
    if layout:
        from dgtd.backends.compiled import driver

        monkeypatch.setattr(driver, "LAYOUT", layout)
    a = small_run(backend, block=7, sampling=Sampling("markov"), noise="bernoulli")
    b = small_run(backend, block=4096, sampling=Sampling("markov"), noise="bernoulli")
    assert_array_equal(a.w_last, b.w_last)
    assert_array_equal(a.w_tail, b.w_tail)
    assert_array_equal(a.info["messages"], b.info["messages"])


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_tail_average_is_the_mean_of_the_last_window(backend):
    """w_tail is the mean of w_k over the last window, k = T - window .. T - 1: the running sum at T less its
    value at T - window, which a run of T - window steps (the same seed, so the same first steps) reports as
    its own window * w_avg. Tolerance 1e-12 relative: the two ways of summing differ by rounding only."""
    T, seeds = 300, 2
    full, head = small_run(backend, seeds=seeds, T=T), small_run(backend, seeds=seeds, T=T // 2)
    assert full.tail_window == T // 2
    want = (T * full.w_avg - (T // 2) * head.w_avg) / (T // 2)
    assert_allclose(full.w_tail, want, rtol=1e-12, atol=1e-12 * np.abs(want).max())
    assert not np.allclose(full.w_tail, full.w_avg)  # the window is not the whole run


def test_numba_matches_numpy_with_the_regulariser():
    """DGTD's rho terms, off-policy on trajectories, in the compiled step (every other setting of every algorithm:
    tests/backends/test_compiled_steps.py)."""
    problem = random_mdp_problem(4, (2, 2, 1, 2), 3, np.random.default_rng(5))
    ref, fast = (
        small_run(backend, problem=problem, sampling=Sampling("markov"), rho=0.05) for backend in ("numpy", "numba")
    )
    scale = np.abs(ref.w_last).max()
    assert_allclose(fast.w_last, ref.w_last, rtol=1e-9, atol=1e-9 * scale)
    assert_allclose(fast.w_avg, ref.w_avg, rtol=1e-9, atol=1e-9 * scale)
    assert_array_equal(fast.info["messages"], ref.info["messages"])


@pytest.mark.parametrize("layout", ["seeds", "agents"])
def test_numba_draws_in_kernel_the_samples_of_a_block(layout, monkeypatch):
    """The compiled driver draws its own samples (`Draws`); fed the materialised `Block` of the same streams
    instead, it must give the same numbers to the last bit, block after block."""
    from dgtd.backends.compiled import driver

    monkeypatch.setattr(driver, "LAYOUT", layout)
    case = dict(sampling=Sampling("markov"), noise="uniform", block=37)
    fused = small_run("numba", **case)
    monkeypatch.setattr(driver.run_block, "draws_samples", False)
    blocks = small_run("numba", **case)
    assert_array_equal(fused.w_last, blocks.w_last)
    assert_array_equal(fused.w_avg, blocks.w_avg)
    assert_array_equal(fused.info["messages"], blocks.info["messages"])


def test_the_layouts_are_chosen_by_what_they_measure():
    """Where both layouts fit, the faster as measured runs (the agent layout until measured, its first piece not
    counted), the other measured again after RECHECK_SECONDS; a piece takes about PIECE_SECONDS at the rate measured."""
    from dgtd.backends.compiled.driver import Layouts

    layouts = Layouts(("agents", "seeds"), 1000)
    assert layouts._choose() == "agents"
    layouts.rate["agents"] = 2e6
    assert layouts._choose() == "seeds"  # not measured yet
    layouts.rate["seeds"] = 3e6
    assert layouts._choose() == "seeds" and layouts._piece("seeds", 10**6) == int(0.1 * 3e6 / 1000)
    layouts.since_check = Layouts.RECHECK_SECONDS
    assert layouts._choose() == "agents" and layouts.since_check == 0.0
    assert layouts._choose() == "seeds"


def test_paper_example_1_converges():
    # Budget: 10^6 iterations (the scenario's default), 3 seeds, numba (a few seconds). Criterion of the paper's
    # Example 1: every agent's averaged iterate within 5 % of w* (relative, max norm). Measured margins are
    # several-fold (about 1 %), so the seeded outcome is far from the threshold.
    sc = get_scenario("paper-example-1")
    res = run(
        sc.problem,
        sc.network,
        sc.algorithm,
        sc.sampling,
        RunSettings(iterations=sc.iterations, seeds=3, seed=0, backend="numba"),
    )
    assert res.metrics["error_avg"][-1].max() < 0.05
    assert np.abs(res.w_tail - res.w_star).max() / np.abs(res.w_star).max() < 0.05
    assert res.metrics["consensus"][-1].max() < 1e-3 * res.metrics["consensus"].max()


def test_random_30_state_6_agent_problem_converges():
    # Budget: 2 * 10^5 iterations x 4 seeds (about a second). Measured worst averaged error about 0.7 %.
    p = random_problem(30, 6, 5, np.random.default_rng(2024), gamma=0.8)
    net = random_edges(topologies.ring(6), 0.7)
    res = run(p, net, DGTD(alpha0=1.0, beta=10), Sampling(), RunSettings(iterations=200_000, seeds=4, backend="numba"))
    assert res.metrics["error_avg"][-1].max() < 0.05
    # Consensus: the agents' disagreement at the end is far below its peak.
    assert res.metrics["consensus"][-1].max() < 0.01 * res.metrics["consensus"].max()


def test_kappa_speeds_consensus():
    # Same samples, kappa = 0 versus kappa = 2: the kappa term of eq. (Lagrangian2) is a consensus force,
    # so the disagreement over the second half of the run is smaller with it (seeded, 4 seeds, 20 000 steps).
    p = random_problem(6, 5, 3, np.random.default_rng(8))
    net = random_edges(topologies.path(5), 0.5)
    out = {}
    for kappa in (0.0, 2.0):
        r = run(
            p,
            net,
            DGTD(alpha0=0.5, beta=10, kappa=kappa),
            Sampling(),
            RunSettings(iterations=20_000, seeds=4, backend="numba", checkpoints=40),
        )
        out[kappa] = r.metrics["consensus"][len(r.steps) // 2 :].mean()
    assert out[2.0] < 0.5 * out[0.0]


def test_network_must_match_agents(small_problem):
    from dgtd.errors import DgtdInputError

    with pytest.raises(DgtdInputError, match="agents"):
        run(small_problem, random_edges(topologies.ring(3)), DGTD(), Sampling(), RunSettings(iterations=5))


def test_periodic_chain_refused_for_markov_sampling():
    from dgtd.errors import DgtdInputError
    from dgtd.problems.model import make_problem

    p = make_problem([[0, 1], [1, 0]], [[1, 0]], [[1.0], [0.5]], 0.9)
    with pytest.raises(DgtdInputError, match="periodic"):
        run(p, random_edges(topologies.path(1)), DGTD(), Sampling("markov"), RunSettings(iterations=5))
    run(p, random_edges(topologies.path(1)), DGTD(), Sampling("iid"), RunSettings(iterations=5))


def test_settings_validation():
    from dgtd.errors import DgtdInputError

    for bad in (dict(iterations=0), dict(seeds=0), dict(tail_fraction=0.0), dict(backend="gpu")):
        with pytest.raises(DgtdInputError):
            RunSettings(**bad)
    with pytest.raises(DgtdInputError):
        dataclasses.replace(DGTD(), kappa=-1.0)


TALKING = [name for name, cls in ALGORITHMS.items() if cls.messages]


@pytest.mark.parametrize(
    "name, layout", [(name, "seeds") for name in TALKING] + [agent_layout_param(name, "agents") for name in TALKING]
)
def test_numba_relabelled_rows_match_numpy(layout, name, monkeypatch):
    """Large graphs are stored in reverse Cuthill-McKee order inside the compiled driver (lowered here to 8 agents):
    samples, rewards, messages and results must still belong to the right agents."""
    from dgtd.algorithms import make_algorithm
    from dgtd.backends.compiled import driver
    from dgtd.backends.compiled import graph as numba_graph

    monkeypatch.setattr(driver, "LAYOUT", layout)
    monkeypatch.setattr(numba_graph, "RELABEL_MIN_AGENTS", 8)
    monkeypatch.setattr(numba_graph, "NEARBY_ROWS", 3)  # twelve agents are all near at the default distance
    rng = np.random.default_rng(8)
    problem = random_problem(6, 12, 3, rng, reward_noise="uniform")
    net = random_edges(
        topologies.from_edges(12, [(i, (i + 5) % 12) for i in range(12)] + [(0, 1), (3, 4)], "chords"), 0.7
    )
    alg = make_algorithm(name, alpha0=0.5, beta=10.0)
    settings = RunSettings(iterations=200, seeds=2, seed=4, checkpoints=4, block_size=64)
    ref = run(problem, net, alg, Sampling("markov"), dataclasses.replace(settings, backend="numpy"))
    fast = run(problem, net, alg, Sampling("markov"), dataclasses.replace(settings, backend="numba"))
    scale = np.abs(ref.w_last).max()
    assert_allclose(fast.w_last, ref.w_last, rtol=1e-9, atol=1e-9 * scale)
    assert_allclose(fast.w_avg, ref.w_avg, rtol=1e-9, atol=1e-9 * scale)
    order = numba_graph.storage_order(type("Ctx", (), {"network": net})())
    assert order is not None and not np.array_equal(order[0], np.arange(12))  # the rows really were reordered


@pytest.mark.parametrize("kind", ["small-world", "geometric"])
def test_a_graph_numbered_near_by_its_generator_keeps_its_numbering_without_a_search(kind, monkeypatch):
    """A chunked small-world's or geometric graph's agents are numbered near their neighbours by construction (a
    ring, cells): the run keeps that numbering (the ranks' blocks are its own) without reverse Cuthill-McKee over the
    whole graph, which kept it anyway (checked: the search, asked, keeps the identity too)."""
    import scipy.sparse.csgraph

    from dgtd.backends.compiled import graph as numba_graph
    from dgtd.config import _network

    net = _network(kind, 20_000, 0.9)
    assert net.base.near and numba_graph._rcm_order(dataclasses.replace(net.base, near=False)) is None

    def refused(*args, **kwargs):
        raise AssertionError("reverse Cuthill-McKee was run")

    monkeypatch.setattr(scipy.sparse.csgraph, "reverse_cuthill_mckee", refused)
    assert numba_graph.storage_order(type("Ctx", (), {"network": net})()) is None
    assert not _network("sparse-random", 500, 0.9).base.near  # (a random graph's numbering is not near)


def test_agents_are_reordered_only_where_that_makes_more_edges_local():
    """A ring with random chords is local as numbered (its ring edges) and stays so; the same graph with its agents
    numbered at random is reordered, and its reordering makes most edges local again."""
    from dgtd.backends.compiled import graph as numba_graph

    rng = np.random.default_rng(0)
    n = 2000
    edges = [(i, (i + 1) % n) for i in range(n)] + [tuple(rng.choice(n, 2, replace=False)) for _ in range(n)]

    def ctx(graph):
        return type("Ctx", (), {"network": random_edges(graph, 0.9)})()

    assert numba_graph.storage_order(ctx(topologies.from_edges(n, edges, "ring-chords"))) is None
    label = rng.permutation(n)
    ring = [(label[i], label[(i + 1) % n]) for i in range(n)]
    order = numba_graph.storage_order(ctx(topologies.from_edges(n, ring, "shuffled-ring")))
    assert order is not None
    assert (
        numba_graph._local_fraction(np.array(ring), order[1])
        > 0.9
        > numba_graph._local_fraction(np.array(ring), np.arange(n))
    )


@pytest.mark.parametrize(
    "user, expected", [({}, "10000"), ({"OMP_WAIT_POLICY": "PASSIVE"}, None), ({"GOMP_SPINCOUNT": "0"}, "0")]
)
def test_openmp_spin_default_keeps_what_the_user_set(user, expected):
    """Importing dgtd sets a short OpenMP spin (agent-parallel kernels hand over between steps without a wake-up),
    unless the user chose a waiting policy or a spin count."""
    env = {k: v for k, v in cli_env().items() if k not in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")} | user
    code = "import os, dgtd; print(os.environ.get('GOMP_SPINCOUNT'))"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    assert out.strip() == str(expected)


@pytest.mark.parametrize("layout", ["seeds", "agents"])
def test_numba_empty_block_changes_nothing(layout, monkeypatch):
    """A block of no steps leaves the state, the running sums and the sample streams as they were (the agent
    layout draws a step's samples ahead of its updates: none may be drawn here)."""
    from dgtd.backends.compiled import driver
    from dgtd.run.loop import prepare
    from dgtd.sources.model import ModelSource

    monkeypatch.setattr(driver, "LAYOUT", layout)
    problem = random_problem(5, 4, 3, np.random.default_rng(3), reward_noise="bernoulli")
    net, alg, B = random_edges(topologies.ring(4), 0.6), DGTD(alpha0=0.5, beta=10), 2
    ctx, *_ = prepare(problem, net, alg, Sampling(), RunSettings(iterations=10, seeds=B))
    source = ModelSource(problem, net, Sampling(), ctx.tables, 0, range(B), "numba")
    source.start()
    cursor = source.streams.cursor().copy()
    state = alg.init(B, 4, 3)._replace(w=np.ones((B, 4, 3)))
    w_sum = np.full((B, 4, 3), 2.0)
    channel = ctx.channel.init(B, ctx.arcs)
    new_state, new_channel, new_sum = driver.run_block(ctx, state, channel, w_sum, np.zeros(0), source.draws(0))
    for before, after in zip(state, new_state):
        assert_array_equal(before, after)
    assert_array_equal(new_sum, w_sum)
    assert_array_equal(new_channel.messages, channel.messages)
    assert_array_equal(source.streams.cursor(), cursor)
