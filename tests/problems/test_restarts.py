"""Episodic tasks under the two conventions of what a sample is: dgtd's (the terminal state's restart transition is a
sample like any other) and the RL-Glue suites' (an episode's samples are its transitions out of non-terminal
states; the restart is not one). The exact quantities, the samplers of both backends and the CLI."""

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from dgtd.errors import DgtdInputError
from dgtd.graphs import topologies
from dgtd.graphs.random import random_edges
from dgtd.problems import exact, tasks
from dgtd.problems.model import make_problem, with_restarts
from dgtd.sources.model import ModelSource, SamplerTables, Sampling


def skipped_boyan(**kw):
    return with_restarts(tasks.boyan(n_agents=4, **kw), "skipped")


def test_skipped_restarts_weight_only_the_non_terminal_states():
    """d is the chain of episodes' stationary distribution conditioned on a non-terminal state; w* solves the
    TD fixed point A w = b with A and b summed by hand over the transitions out of non-terminal states."""
    p = tasks.boyan(n_agents=4)
    m, ms = exact.Moments(p), exact.Moments(with_restarts(p, "skipped"))
    t = p.terminal
    assert ms.d[t].sum() == 0.0
    assert_allclose(ms.d[~t], m.d[~t] / m.d[~t].sum(), rtol=1e-12)
    S, Phi, r = p.n_states, p.Phi, p.R.mean(axis=0)
    d = ms.d
    A = sum(
        d[s] * p.P[s, u] * np.outer(Phi[s], Phi[s] - 0.95 * (not t[u]) * Phi[u])
        for s in range(S)
        if not t[s]
        for u in range(S)
    )
    b = sum(d[s] * r[s] * Phi[s] for s in range(S) if not t[s])
    w_hand = np.linalg.solve(A, b)
    assert_allclose(exact.w_star(ms), w_hand, rtol=1e-9)
    assert np.abs(exact.w_star(ms) - exact.w_star(m)).max() > 0.05  # the convention changes the answer here


def test_with_values_in_the_features_both_conventions_agree():
    """13 states and gamma 1: the true values are linear in the features (w* = (-24, -16, -8, 0)), so any
    weighting of the states gives the same TD fixed point."""
    m = exact.Moments(skipped_boyan(n_states=13, gamma=1.0))
    assert_allclose(exact.w_star(m), [-24.0, -16.0, -8.0, 0.0], atol=1e-9)


def test_skipped_restarts_need_an_episodic_task_and_a_known_convention():
    from dgtd.problems.generators import random_problem

    with pytest.raises(DgtdInputError, match="episodic"):
        with_restarts(random_problem(4, 2, 2, np.random.default_rng(0)), "skipped")
    with pytest.raises(DgtdInputError, match="sampled, skipped"):
        with_restarts(tasks.boyan(n_agents=2), "never")


def _source(problem, mode, backend, shared=False):
    m = exact.Moments(problem)
    net = random_edges(topologies.ring(problem.n_agents), 0.5)
    src = ModelSource(problem, net, Sampling(mode, shared), SamplerTables.build(problem, m.d), 3, range(2), backend)
    src.start()
    return src


@pytest.mark.parametrize("mode", ["iid", "markov"])
def test_no_sample_starts_at_a_terminal_state_and_states_follow_d(mode):
    # 20 000 steps x 2 seeds x 4 agents = 160 000 samples (correlated along Markovian trajectories, about 4 steps
    # apart): each frequency's standard error is below 0.003, so 0.012 is over 4 standard errors.
    p = skipped_boyan()
    blk = _source(p, mode, "numpy").next_block(20_000)
    assert not p.terminal[blk.s].any()
    assert p.terminal[blk.s_next].any()  # the transition into the terminal state is still a sample
    d = exact.Moments(p).d
    assert_allclose(np.bincount(blk.s.ravel(), minlength=p.n_states) / blk.s.size, d, atol=0.012)
    if mode == "markov":  # a trajectory goes on from s' unless s' is terminal; then from the restart's state
        going_on = ~p.terminal[blk.s_next[:-1]]
        assert_array_equal(blk.s[1:][going_on], blk.s_next[:-1][going_on])
        assert set(blk.s[1:][~going_on].tolist()) == {0}  # Boyan's episodes start at state 0


@pytest.mark.parametrize("mode", ["iid", "markov"])
def test_compiled_sampler_skips_restarts_as_the_reference_does(mode):
    p = skipped_boyan()
    a, b = _source(p, mode, "numpy", shared=True), _source(p, mode, "numba", shared=True)
    for T in (7, 300):
        x, y = a.next_block(T), b.next_block(T)
        assert_array_equal(x.s, y.s)
        assert_array_equal(x.s_next, y.s_next)
        assert_array_equal(x.r, y.r)


@pytest.mark.parametrize("algorithm", ["td0", "dgtd"])
def test_fused_kernels_skip_restarts_as_the_reference_does(algorithm):
    from dgtd.algorithms import make_algorithm
    from dgtd.run.loop import evaluate

    p = skipped_boyan()
    net = random_edges(topologies.ring(4), 0.5)
    alg = make_algorithm(algorithm, alpha0=0.05)
    runs = [
        evaluate(p, net, alg, sampling=Sampling("markov"), iterations=500, seeds=2, backend=b, checkpoints=5)
        for b in ("numpy", "numba")
    ]
    assert_allclose(runs[0].w_last, runs[1].w_last, rtol=1e-12, atol=1e-12)


def tiny_episodic_task():
    """Three states that each stay or move on with probability 1/2, then a terminal state that restarts at the
    first; two features that alias the terminal state with the second, so that the weighting matters: the two
    conventions' w* are over 50 % apart in value error."""
    P = np.array([[0.5, 0.5, 0, 0], [0, 0.5, 0.5, 0], [0, 0, 0.5, 0.5], [1, 0, 0, 0.0]])
    R = np.array([[1, 0, 2, 0.0], [0, 1, 1, 0.0]])
    Phi = np.array([[1, 0], [1, 1], [0, 1], [1, 1.0]])
    return make_problem(P, R, Phi, 0.9, terminal=np.array([0, 0, 0, 1]), name="tiny")


@pytest.mark.parametrize("mode", ["iid", "markov"])
def test_a_long_run_reaches_the_skipped_convention_s_w_star(mode):
    """Centralised TD(0), 200 000 steps of 0.2/sqrt(k+100), 2 seeds: the tail average ends within 2 % of the skipped
    convention's w* in value error (measured: under 0.5 %), while the other convention's is 51 % away."""
    from dgtd.algorithms import make_algorithm
    from dgtd.run.loop import evaluate

    p = with_restarts(tiny_episodic_task(), "skipped")
    m = exact.Moments(p)
    w_star, other = exact.w_star(m), exact.w_star(exact.Moments(tiny_episodic_task()))
    assert exact.value_error(m, other[None], w_star)[0] > 0.5
    alg = make_algorithm("td0", alpha0=0.2, beta=100.0)
    run = evaluate(
        p,
        random_edges(topologies.ring(2)),
        alg,
        sampling=Sampling(mode, True),
        iterations=200_000,
        seeds=2,
        checkpoints=4,
    )
    assert exact.value_error(m, run.w_tail.reshape(-1, 2), w_star).max() < 0.02
