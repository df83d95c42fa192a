"""The patrol world of the paper's Example 2: motion, grid, rewards, the sample source and the estimated chain."""

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from scipy.integrate import solve_ivp

from dgtd.algorithms.dgtd import DGTD
from dgtd.errors import DgtdInputError
from dgtd.graphs.proximity import ProximityNetwork
from dgtd.problems import exact
from dgtd.problems.estimated import chain_from_counts, minibatch_td, tabular_w_star
from dgtd.problems.features import tabular
from dgtd.problems.model import make_problem
from dgtd.run.loop import RunSettings, run
from dgtd.scenarios.robots import (
    PatrolSource,
    PatrolWorld,
    cell_index,
    map_correlation,
    move,
    patrol_scenario,
    region_cells,
    reward_table,
    simulate_reference,
    trajectory,
)
from dgtd.streams import AGENT_START, AGENT_STATE, seed_key, uniforms

# A small world for fast tests: a 10 m square on a 5 x 5 grid (2 m cells), two robots, two corner regions.
SMALL = PatrolWorld(size=10.0, grid=5, regions=((0.0, 6.0, 4.0, 10.0), (6.0, 0.0, 10.0, 4.0)))


def test_cells_are_row_major_from_the_origin_and_the_far_boundary_is_in_the_last_cell():
    w = PatrolWorld()
    x = np.array([[0.0, 0.0], [19.99, 0.0], [0.0, 1.0], [5.5, 3.2], [20.0, 20.0]])
    assert cell_index(w, x).tolist() == [0, 19, 20, 3 * 20 + 5, 399]


def test_regions_reward_only_their_own_robot():
    w = PatrolWorld()
    cells = region_cells(w)
    assert cells.sum(axis=1).tolist() == [5 * 6, 6 * 4, 6 * 4]  # the rectangles in whole 1 m cells
    assert cells.sum(axis=0).max() == 1  # disjoint
    R = reward_table(w)
    assert set(np.unique(R)) == {0.0, 100.0}
    assert_array_equal(R > 0, cells)
    assert cells[0, cell_index(w, np.array([4.5, 15.5]))] and not cells[1, cell_index(w, np.array([4.5, 15.5]))]


def test_move_is_the_exact_flow_of_the_control_law():
    """x' = -h (x - r) has x(t) = r + exp(-h t)(x0 - r): n steps of dt must equal an ODE solver at t = n dt."""
    w = PatrolWorld(gain=0.7, dt=0.3, arrival_radius=1e-9)
    x0, r = np.array([1.0, 2.0]), np.array([15.0, 11.0])
    x, rr = x0, r
    for _ in range(10):
        x, rr = move(w, x, rr, np.array([0.5, 0.5]))
    assert_array_equal(rr, r)  # never arrived: the waypoint is kept
    ode = solve_ivp(lambda t, y: -w.gain * (y - r), (0, 10 * w.dt), x0, rtol=1e-11, atol=1e-12)
    assert_allclose(x, ode.y[:, -1], rtol=1e-8)
    assert_allclose(x, r + np.exp(-w.gain * 10 * w.dt) * (x0 - r), rtol=1e-13)


def test_a_new_uniform_waypoint_is_drawn_on_arrival_only():
    w = PatrolWorld()  # contraction exp(-0.25) = 0.7788; arrival within 0.5 m
    r = np.array([[10.0, 10.0], [10.0, 10.0]])
    x = np.array([[10.6, 10.0], [11.0, 10.0]])  # after one step: 0.467 m (arrived) and 0.779 m (not yet)
    u = np.array([[0.25, 0.75], [0.1, 0.1]])
    x1, r1 = move(w, x, r, u)
    assert_allclose(x1[:, 0] - 10.0, [0.6 * w.contraction, 1.0 * w.contraction])
    assert_allclose(r1, [[5.0, 15.0], [10.0, 10.0]])


def test_bad_world_parameters_are_refused():
    with pytest.raises(DgtdInputError, match="inside the area"):
        PatrolWorld(regions=((0.0, 0.0, 25.0, 3.0),))
    with pytest.raises(DgtdInputError, match="positive"):
        PatrolWorld(gain=0.0)


def source(seed_ids=range(3), seed=7, world=None):
    world = PatrolWorld() if world is None else world
    src = PatrolSource(world, ProximityNetwork(world.n_robots, 5.0), seed, seed_ids)
    src.start()
    return src


def test_source_blocks_concatenate_and_follow_one_trajectory():
    a, b = source(), source()
    one = a.next_block(60)
    parts = [b.next_block(n) for n in (1, 25, 34)]
    for field in ("s", "a", "s_next", "r", "up"):
        assert_array_equal(getattr(one, field), np.concatenate([getattr(p, field) for p in parts]))
    assert one.s.shape == (60, 3, 3) and one.up.shape == (60, 3, 3) and one.r.shape == (60, 3, 3)
    assert_array_equal(one.s[1:], one.s_next[:-1])  # Markovian: each transition starts where the last ended
    assert_array_equal(one.a, 0)
    assert_array_equal(one.r, reward_table(PatrolWorld())[np.arange(3), one.s])  # agent i's reward at its own cell


def test_a_seeds_samples_do_not_depend_on_the_other_seeds():
    alone = source(seed_ids=[2]).next_block(40)
    together = source(seed_ids=[0, 1, 2]).next_block(40)
    for field in ("s", "s_next", "r", "up"):
        assert_array_equal(getattr(alone, field)[:, 0], getattr(together, field)[:, 2])


def test_links_are_the_proximity_graph_of_the_robots_positions():
    """Replay seed 0's uniforms by hand: the masks must be the positions' proximity links at each step."""
    src = source(seed_ids=[0])
    blk = src.next_block(200)
    key, robots = np.uint64(seed_key(7, 0)), np.arange(3)
    start = [uniforms(key, AGENT_START, 0, robots, j) for j in (0, 1)]  # 4 per robot: x, y, then the waypoint
    u0 = np.stack([start[0][0], start[0][1], start[1][0], start[1][1]], axis=-1)
    moves = np.stack(uniforms(key, AGENT_STATE, np.arange(200, dtype=np.uint64)[:, None], robots), axis=-1)
    w = PatrolWorld()
    X, _ = trajectory(w, w.size * u0[:, :2], w.size * u0[:, 2:], moves)
    net = ProximityNetwork(3, 5.0)
    assert_array_equal(blk.up[:, 0], net.masks(X[:-1]))
    assert_array_equal(blk.s[:, 0], cell_index(w, X[:-1]))
    assert 0 < blk.up.mean() < 1  # the robots do meet, and part


def test_source_state_round_trip_resumes_identically():
    a = source()
    a.next_block(30)
    saved = a.get_state()
    first = a.next_block(30)
    a.set_state(saved)
    again = a.next_block(30)
    for field in ("s", "s_next", "r", "up"):
        assert_array_equal(getattr(first, field), getattr(again, field))


def test_link_statistics_of_the_source_match_its_masks():
    src = source()
    up = np.concatenate([src.next_block(100).up, src.next_block(50).up])
    assert src.stats.steps == 150 * 3
    assert_allclose(src.stats.link_frequency, up.reshape(-1, 3).mean(axis=0))


def test_estimated_chain_is_stochastic_and_its_stationary_distribution_matches_visits():
    ref = simulate_reference(SMALL, ProximityNetwork(2, 4.0), teams=40, steps=1000, seed=1)
    assert np.all(ref.P >= 0)
    assert_allclose(ref.P.sum(axis=1), 1.0, atol=1e-12)
    assert ref.n_transitions == 40 * 2 * 1000
    # Counted origins and destinations differ only by each robot's first and last state: |f P - f|_1 <= 2 R / n.
    robots = 80
    assert np.abs(ref.visits @ ref.P - ref.visits).sum() <= 2 * robots / ref.n_transitions + 1e-12
    # So the visits are almost stationary for P_hat, and d of P_hat is that small imbalance (2 R / n = 2e-3 here)
    # propagated through the chain's fundamental matrix: measured 3.8e-4; the bound 2e-3 leaves a factor 5.
    assert np.abs(ref.d - ref.visits).max() < 2e-3
    assert_allclose(ref.d @ ref.P, ref.d, atol=1e-12)


def test_the_estimate_converges_as_the_run_grows():
    """Two independent runs of n steps differ by O(1/sqrt(n)): 16 times longer runs must differ about 4 times less.

    Measured ratios are 0.27 (P) and 0.25 (d); asserting < 0.5 leaves room for the runs' own randomness."""
    net = ProximityNetwork(2, 4.0)

    def gap(steps):
        a, b = (simulate_reference(SMALL, net, 40, steps, seed=s, replicates=1) for s in (1, 2))
        return np.abs(a.P - b.P).max(), np.abs(a.d - b.d).sum(), np.abs(a.w_star - b.w_star).max()

    short, long = gap(250), gap(4000)
    assert long[0] < 0.5 * short[0]
    assert long[1] < 0.5 * short[1]
    assert long[2] < 0.5 * short[2]


def test_reference_w_star_is_the_exact_solution_of_the_estimated_chain():
    ref = simulate_reference(SMALL, ProximityNetwork(2, 4.0), teams=40, steps=1000, seed=3)
    problem = make_problem(ref.P, reward_table(SMALL), tabular(SMALL.n_states), SMALL.gamma)
    m = exact.Moments(problem)
    assert_allclose(exact.w_star(m), ref.w_star, rtol=1e-10)
    assert_allclose(ref.w_star, reward_table(SMALL).mean(0) + SMALL.gamma * ref.P @ ref.w_star, rtol=1e-10)
    assert_allclose(m.d, ref.d, atol=1e-12)
    # The centralised TD(0) on the same samples lands within 1 % of max w* (measured 0.2 %).
    assert np.abs(ref.w_td - ref.w_star).max() < 0.01 * ref.w_star.max()
    assert ref.w_replicates.shape == (4, SMALL.n_states)


def test_unvisited_states_are_reported_with_a_fix():
    with pytest.raises(DgtdInputError, match="never visited.*lengthen"):
        chain_from_counts(np.array([[1, 1], [0, 0]]))


def test_minibatch_td_on_a_hand_computed_case():
    # Two states, w = (1, 2), gamma 0.5, r = (3, 0); samples (0 -> 1), (0 -> 0), (1 -> 0); first visits.
    w, n = minibatch_td(
        np.array([1.0, 2.0]),
        np.array([0, 0]),
        np.array([0, 0, 1]),
        np.array([1, 0, 0]),
        np.array([3.0, 0.0]),
        0.5,
        omega=1.0,
    )
    # deltas: 3 + 1 - 1 = 3, 3 + 0.5 - 1 = 2.5, 0 + 0.5 - 2 = -1.5; steps min(1, c / n^omega) = 1 for both states
    assert_allclose(w, [1.0 + 2.75, 2.0 - 1.5])
    assert n.tolist() == [2, 1]
    w2, _ = minibatch_td(
        np.array([1.0, 2.0]), np.array([6, 0]), np.array([0, 0]), np.array([1, 0]), np.array([3.0, 0.0]), 0.5, omega=1.0
    )
    assert_allclose(w2[0], 1.0 + (2 / 8) * 2.75)  # c = 2 samples, n = 8 so far: step 2/8 on the mean delta


def test_tabular_w_star_solves_the_bellman_equation():
    P = np.array([[0.5, 0.5], [0.2, 0.8]])
    r = np.array([1.0, 0.0])
    w = tabular_w_star(P, r, 0.9)
    assert_allclose(w, r + 0.9 * P @ w)


def test_map_correlation():
    ref = np.array([0.0, 1.0, 2.0, 3.0])
    assert_allclose(
        map_correlation(np.stack([2 * ref + 5, -ref, ref**2]), ref), [1.0, -1.0, np.corrcoef(ref**2, ref)[0, 1]]
    )


def small_scenario(iterations=100_000, schedule="sqrt", alpha0=10.0, beta=1000.0):
    return patrol_scenario(
        SMALL,
        4.0,
        algorithm=DGTD(alpha0=alpha0, beta=beta, schedule=schedule, kappa=3.0),
        iterations=iterations,
        name="small-patrol",
        description="a small patrol world",
        reference_teams=200,
        reference_steps=2000,
    )


def test_numpy_and_numba_kernels_agree_on_the_patrol_source():
    sc = small_scenario()
    out = {}
    for backend in ("numpy", "numba"):
        settings = RunSettings(iterations=1500, seeds=2, checkpoints=5, backend=backend, block_size=256)
        out[backend] = run(sc.problem, sc.network, sc.algorithm, sc.sampling, settings, source=sc.source(3, range(2)))
    assert_allclose(out["numba"].w_last, out["numpy"].w_last, rtol=1e-9, atol=1e-9)
    assert_allclose(out["numba"].w_avg, out["numpy"].w_avg, rtol=1e-9, atol=1e-9)


def test_small_grid_agents_agree_with_each_other_and_with_the_reference():
    """5 x 5 grid, two robots linked within 4 m (half the time), 100 000 steps of DGTD, four seeds.

    Tolerances, from runs of six seeds (worst seen: tail-averaged sup error 0.10, correlation 0.983, relative
    consensus 0.017): the tail-averaged map (second half of the run, whose error the paper's rates bound)
    within 20 % of max w* in every state, the last map's correlation with w* above 0.95, and each agent's
    RMS distance from the agents' mean below 4 % of |w*|_2. The reference itself is accurate to 0.2 %.
    """
    sc = small_scenario()
    ref = sc.report.reference
    assert ref.summary()["w_star_stderr_relative"] < 0.005
    settings = RunSettings(iterations=sc.iterations, seeds=4, checkpoints=10, backend="numba")
    res = run(sc.problem, sc.network, sc.algorithm, sc.sampling, settings, source=sc.source(0, range(4)))
    assert_allclose(res.w_star, ref.w_star, rtol=1e-9)
    scale = res.w_star.max()
    assert np.abs(res.w_tail - res.w_star).max() < 0.2 * scale
    assert map_correlation(res.w_last, res.w_star).min() > 0.95
    spread = np.sqrt(exact.consensus_error(res.w_last) / 2) / np.linalg.norm(res.w_star)
    assert spread.max() < 0.04
    # every agent learnt both regions although it senses one: its map is high on the other robot's region too
    cells = region_cells(SMALL)
    for i, j in ((0, 1), (1, 0)):
        assert res.w_tail[:, i, cells[j]].mean() > 0.5 * ref.w_star[cells[j]].mean()


def test_paper_example_2_scenario():
    from dgtd.scenarios import get_scenario

    sc = get_scenario("paper-example-2")
    p = sc.problem
    assert (p.n_states, p.n_agents, p.n_features, p.gamma, sc.iterations) == (400, 3, 400, 0.5, 50_000)
    assert_array_equal(p.Phi, np.eye(400))
    assert_array_equal(p.R, reward_table(PatrolWorld()))
    assert sc.network.n_edges == 3 and np.all((0.1 < sc.network.p) & (sc.network.p < 0.4))
    src = sc.source(0, range(2))
    assert isinstance(src, PatrolSource) and src.network.radius == 5.0
    assert_array_equal(src.edges, sc.network.base.edges)
    ref = sc.report.reference
    assert ref.n_transitions >= 10_000_000 and ref.counts.sum(axis=1).min() > 1000
    assert ref.summary()["w_star_stderr_relative"] < 0.01
    assert get_scenario("paper-example-2") is sc  # built once per process
    with pytest.raises(DgtdInputError, match="edge-prob does not apply"):
        get_scenario("paper-example-2", edge_prob=0.5)


def test_a_simulators_kernel_is_loaded_before_the_first_step_not_inside_it(monkeypatch):
    """With a simulator's source the compiled kernel runs first on an empty block (it loads or compiles there, and
    is announced), then on the steps: a compilation inside the first step showed as a stalled run with an ETA of
    hundreds of hours."""
    import dgtd.run.layout as layout

    real, lengths = layout.kernel_for, []

    def recording(backend, name, channel=None):
        kernel = real(backend, name, channel)
        return lambda ctx, state, channel, sums, alpha, block: (
            lengths.append(len(alpha)),
            kernel(ctx, state, channel, sums, alpha, block),
        )[1]

    monkeypatch.setattr(layout, "kernel_for", recording)
    sc = small_scenario()
    events = []
    settings = RunSettings(iterations=300, seeds=1, checkpoints=3, backend="numba", block_size=100)
    run(
        sc.problem,
        sc.network,
        sc.algorithm,
        sc.sampling,
        settings,
        source=sc.source(0, range(1)),
        progress=lambda n: events.append("step"),
        kernel_ready=lambda s: events.append("ready"),
    )
    assert lengths[0] == 0 and sum(lengths) == 300, lengths
    assert events[0] == "ready" and events.count("ready") == 1 and "step" in events
