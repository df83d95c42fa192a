import numpy as np
import pytest

from dgtd.problems.generators import random_mdp_problem, random_problem


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture
def small_problem(rng):
    return random_problem(6, 4, 3, rng, gamma=0.85)


@pytest.fixture
def off_policy_problem(rng):
    return random_mdp_problem(5, (2, 3), 3, rng, gamma=0.8, off_policy=True)
