"""Problem validation, features, and the exact reduction of a multi-agent MDP."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from dgtd.errors import DgtdInputError
from dgtd.problems import exact
from dgtd.problems.features import gaussian_rbf, tabular
from dgtd.problems.mdp import from_mdp, joint_policy
from dgtd.problems.model import make_problem

P2 = [[0.5, 0.5], [0.2, 0.8]]


def test_paper_example_features():
    Phi = gaussian_rbf([1, 2, 3, 4], [0, 4])
    s = np.arange(1, 5)
    assert_allclose(Phi, np.stack([np.exp(-(s**2)), np.exp(-((s - 4) ** 2))], 1))
    assert_allclose(tabular(3), np.eye(3))


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(P=[[0.5, 0.4], [0.2, 0.8]]), "sums to 0.9"),
        (dict(P=[[1.2, -0.2], [0.2, 0.8]]), "negative"),
        (dict(P=[[1.0, 0.0], [0.0, 1.0]]), "not ergodic"),
        (dict(Phi=[[1.0, 2.0], [2.0, 4.0]]), "full column rank"),
        (dict(R=[[1.0, 0.0, 1.0]]), "shape"),
        (dict(Phi=[[1.0], [1.0], [0.0]]), "shape"),
        (dict(gamma=1.0), "gamma"),
        (dict(gamma=0.0), "gamma"),
        (dict(R=[[np.nan, 0.0]]), "NaN"),
        (dict(P=[[np.inf, 0.5], [0.2, 0.8]]), "NaN or infinite"),
        (dict(R=[[-1.0, 0.0]]), ">= 0"),
    ],
)
def test_bad_problems_are_refused(kwargs, match):
    args = dict(P=P2, R=[[1.0, 0.0]], Phi=[[1.0], [2.0]], gamma=0.9) | kwargs
    with pytest.raises(DgtdInputError, match=match):
        make_problem(**args)


def test_joint_policy_is_product(rng):
    p1 = rng.dirichlet(np.ones(2), size=3)
    p2 = rng.dirichlet(np.ones(3), size=3)
    J = joint_policy([p1, p2])
    assert J.shape == (3, 6)
    assert_allclose(J[1, 1 * 3 + 2], p1[1, 1] * p2[1, 2])  # joint action (a_1, a_2) = (1, 2), C order
    assert_allclose(J.sum(1), 1)


def test_from_mdp_reduction_by_hand():
    # Two states, one agent with two actions: a = 0 stays, a = 1 switches; reward 1 for being in state 1 next.
    P = np.zeros((2, 2, 2))
    P[0, 0, 0] = P[1, 0, 1] = 1.0
    P[0, 1, 1] = P[1, 1, 0] = 1.0
    rewards = np.zeros((1, 2, 2, 2))
    rewards[0, :, :, 1] = 1.0
    pi = [np.array([[0.25, 0.75], [0.5, 0.5]])]
    beta = [np.array([[0.5, 0.5], [0.9, 0.1]])]
    p = from_mdp(P, rewards, np.eye(2), 0.5, pi, beta)
    assert_allclose(p.P, [[0.25, 0.75], [0.5, 0.5]])
    assert_allclose(p.R, [[0.75, 0.5]])  # r(s) = P_pi(s, 1)
    assert_allclose(p.ratio, [[0.5, 1.5], [0.5 / 0.9, 5.0]])
    assert_allclose(p.P_behaviour, [[0.5, 0.5], [0.1, 0.9]])
    # w* uses the behaviour's d and the target's P: tabular, so w* = (I - gamma P_pi)^-1 r_pi whatever d is.
    assert_allclose(exact.w_star(exact.Moments(p)), np.linalg.solve(np.eye(2) - 0.5 * p.P, p.R[0]))


def test_off_policy_needs_coverage():
    P = np.ones((2, 2, 2)) / 2
    with pytest.raises(DgtdInputError, match="beta"):
        from_mdp(P, np.ones((1, 2, 2)), np.eye(2), 0.9, [np.array([[0.5, 0.5]] * 2)], [np.array([[1.0, 0.0]] * 2)])


def test_sampling_model_must_reproduce_target():
    with pytest.raises(DgtdInputError, match="reproduce P"):
        make_problem(
            P2,
            [[1.0, 0.0]],
            [[1.0], [2.0]],
            0.9,
            P_sample=np.array(P2)[:, None, :][:, :, ::-1],
            ratio=np.ones((2, 1)),
            R_sample=np.array([[[1.0], [0.0]]]),
        )
