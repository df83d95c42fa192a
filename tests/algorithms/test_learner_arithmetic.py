"""The learners' arithmetic, one definition each (`dgtd.algorithms.actor`, `dgtd.algorithms.team_reward`): NumPy,
numba and JAX run the same functions to the same numbers, the tabular actor is the linear one on one-hot features,
and the actor's step is the gradient of log pi times the advantage."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from dgtd.algorithms.actor import LinearSoftmaxActor, SoftmaxActor, policy, score_step, td_error
from dgtd.algorithms.team_reward import mean_update, regression_rate, regression_step

ARITHMETIC = {
    "td_error": (td_error, 5),
    "score_step": (score_step, 6),
    "regression_step": (regression_step, 3),
    "mean_update": (mean_update, 3),
}


@pytest.mark.parametrize("name", ARITHMETIC)
def test_numpy_numba_and_jax_run_one_definition_to_the_same_numbers(name):
    """Each function on arrays (NumPy, JAX in double precision) and elementwise on scalars, compiled by numba: the
    same operations in the same order, so equal to rounding (1e-15 relative; JAX may fuse a multiply-add)."""
    jax = pytest.importorskip("jax")
    jax.config.update("jax_enable_x64", True)
    f, n_args = ARITHMETIC[name]
    args = np.random.default_rng(3).normal(size=(n_args, 50))
    expected = f(*args)
    compiled = njit(f)
    scalars = np.array([compiled(*column) for column in args.T])
    on_jax = np.asarray(f(*(jax.numpy.asarray(x) for x in args)))
    np.testing.assert_array_equal(scalars, expected)
    np.testing.assert_allclose(on_jax, expected, rtol=1e-15, atol=1e-15)


def test_the_tabular_actor_is_the_linear_actor_on_one_hot_features():
    """pi(. | s) = softmax(theta[s]) is the linear softmax on x = e_s with weights theta^T: the same policies and,
    for one sample, the same step (with an entropy bonus), to rounding."""
    rng = np.random.default_rng(4)
    B, N, S, A = 3, 4, 5, 3
    tabular, linear = SoftmaxActor(entropy=0.3), LinearSoftmaxActor(entropy=0.3)
    theta = rng.normal(size=(B, N, S, A))
    s, a, delta = rng.integers(S, size=B), rng.integers(A, size=(B, N)), rng.normal(size=(B, N))
    x = np.broadcast_to(np.eye(S)[s][:, None, :], (B, N, S))
    weights = theta.transpose(0, 1, 3, 2)  # (B, N, A, S)
    np.testing.assert_allclose(linear.probabilities(weights, x), tabular.probabilities(theta, s), rtol=1e-14)
    step_tabular = tabular.increment(theta, s, a, delta, 0.7)
    step_linear = linear.increment(weights, x, a, delta, 0.7).transpose(0, 1, 3, 2)
    np.testing.assert_allclose(step_linear, step_tabular, rtol=1e-14, atol=1e-16)


def test_the_actors_step_is_the_advantage_times_the_gradient_of_log_pi():
    """score_step's entries are beta delta d log pi(a) / d theta (central differences, 1e-8)."""
    theta, a, beta, delta = np.random.default_rng(5).normal(size=4), 2, 0.3, 1.7
    step = score_step(beta, delta, 0.0, 0.0, np.eye(4)[a], policy(theta))
    numeric = [(np.log(policy(theta + 1e-6 * e)[a]) - np.log(policy(theta - 1e-6 * e)[a])) / 2e-6 for e in np.eye(4)]
    np.testing.assert_allclose(step, beta * delta * np.array(numeric), atol=1e-8)


def test_the_regressions_step_normalises_by_the_features_norm():
    """nu_k |f|^2 = mean_step(k): one step from lambda = 0 on f with N ones, |g|^2 = 2, moves rhat = lambda^T f
    to nu_k |f|^2 r = r / sqrt(1 + k / 100)."""
    N, k, r = 4, 300, 1.5
    nu = regression_rate(k, N, 2.0)
    f = np.full(N, np.sqrt(2.0))  # |f|^2 = N |g|^2 = 8
    lam = regression_step(nu, r, 0.0) * f
    assert lam @ f == pytest.approx(r / np.sqrt(1 + k / 100), rel=1e-14)


def test_the_actors_step_the_advantage_and_the_regression_run_on_jax_as_on_numpy():
    """`actor_increment`, `action_advantage` on `own_values`, and the team-reward regression's `estimate` and
    `add_regression` (both forms of g) take JAX arrays as NumPy ones (their scatter-adds by `dgtd.samples.added`): the
    same numbers to 1e-15 (the same operations in the same order; JAX may fuse a multiply-add). NumPy's adds land in
    the array given, JAX's in a new one."""
    from dgtd.algorithms.actor import action_advantage, actor_increment, own_values
    from dgtd.algorithms.team_reward import add_regression, estimate

    jax = pytest.importorskip("jax")
    jax.config.update("jax_enable_x64", True)
    jnp = jax.numpy
    rng = np.random.default_rng(6)
    B, N, S, A, m = 3, 4, 5, 3, 2
    theta = rng.normal(size=(B, N, S, A))
    theta[:, 1, :, 2] = -np.inf  # agent 1 has two actions
    s, a, delta = rng.integers(S, size=B), rng.integers(2, size=(B, N)), rng.normal(size=(B, N))
    lam, W, g = rng.normal(size=(B, N, N * A * S)), rng.normal(size=(B, N, N * S * A)), rng.normal(size=(B, m))
    agents = np.arange(N)
    pi = policy(theta[np.arange(B)[:, None], agents[None, :], s[:, None]])

    def both(f, *args):
        return f(*args), np.asarray(f(*(jnp.asarray(x) if isinstance(x, np.ndarray) else x for x in args)))

    pairs = [
        both(lambda t, s, a, d: actor_increment(t, s, a, d, 0.7, None, 0.2), theta, s, a, delta),
        both(lambda w, s, p, a: action_advantage(own_values(w, agents, s, S, A), p, a), W, s, pi, a),
        both(lambda lam, a, s: estimate(lam, a, s, A), lam, a, s),
        both(lambda lam, a, s, d: add_regression(lam * 1.0, a, s, A, d), lam, a, s, delta),
        both(lambda lam, a, g: estimate(lam, a, g, A), lam[..., : N * A * m], a, g),
        both(lambda lam, a, g, d: add_regression(lam * 1.0, a, g, A, d), lam[..., : N * A * m], a, g, delta),
    ]
    for on_numpy, on_jax in pairs:
        assert np.abs(on_numpy).sum() > 0
        np.testing.assert_allclose(on_jax, on_numpy, rtol=1e-15, atol=1e-15)
    into = np.zeros_like(theta)
    assert actor_increment(theta, s, a, delta, 0.7, into) is into and np.abs(into).sum() > 0
