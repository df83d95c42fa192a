"""Networked MDPs (`dgtd.problems.networked`): agents with local states, their joint table, keyed steps by agent."""

from __future__ import annotations

import numpy as np
import pytest

from dgtd.errors import DgtdInputError
from dgtd.graphs import topologies
from dgtd.problems import team
from dgtd.problems.networked import NetworkedMDP, neighbourhoods_of, random_networked
from dgtd.streams import seed_keys


def test_an_agents_neighbourhood_is_itself_then_its_neighbours_ascending():
    hoods = neighbourhoods_of(np.array([[0, 1], [1, 2], [3, 1]]), 4)
    assert hoods.tolist() == [[0, 1, -1, -1], [1, 0, 2, 3], [2, 1, -1, -1], [3, 1, -1, -1]]


def test_the_joint_table_is_the_product_of_the_agents_tables():
    """P(s' | s, a) = prod_i P_i(s_i' | s_N_i, a_i) entry by entry (the neighbourhood's states in N_i's order, the first
    the most significant), every row a distribution, and r_i(s_i, a_i) in every joint state and action."""
    mdp = random_networked(topologies.path(3).edges, 3, n_states=2, n_actions=2, seed=4)
    joint = mdp.joint()
    S = 2
    for s, a, t in [((0, 1, 1), (1, 0, 1), (1, 1, 0)), ((1, 0, 0), (0, 0, 1), (0, 1, 1))]:
        here = [s[0] * S + s[1], s[1] * S**2 + s[0] * S + s[2], s[2] * S + s[1]]  # N_0 = (0, 1), N_1 = (1, 0, 2)
        want = np.prod([mdp.P[i, here[i], a[i], t[i]] for i in range(3)])
        got = joint.P[
            np.ravel_multi_index(s, (2,) * 3), np.ravel_multi_index(a, (2,) * 3), np.ravel_multi_index(t, (2,) * 3)
        ]
        assert got == pytest.approx(want, rel=1e-14)
        for i in range(3):
            assert (
                joint.R[i, np.ravel_multi_index(s, (2,) * 3), np.ravel_multi_index(a, (2,) * 3)] == mdp.R[i, s[i], a[i]]
            )
    assert np.allclose(joint.P.sum(axis=-1), 1.0)


def test_keyed_steps_follow_the_agents_tables():
    """40 000 seeds step once from the same states and actions: each agent's next state's frequency within 5 standard
    errors of P_i(. | s_N_i, a_i) (a 5-sigma miss: about 6e-7 a check)."""
    mdp = random_networked(topologies.ring(5).edges, 5, n_states=3, n_actions=2, seed=1)
    B = 40_000
    s, a = np.tile([[0, 2, 1, 1, 0]], (B, 1)), np.tile([[1, 0, 1, 1, 0]], (B, 1))
    s_next, r = mdp.step(s, a, seed_keys(0, range(B)), 7)
    here = mdp.local_index(s[:1], np.arange(5))[0]
    for i in range(5):
        p = mdp.P[i, here[i], a[0, i]]
        freq = np.bincount(s_next[:, i], minlength=3) / B
        assert np.all(np.abs(freq - p) <= 5 * np.sqrt(p * (1 - p) / B) + 1e-12), (i, freq, p)
        assert (r[:, i] == mdp.R[i, s[0, i], a[0, i]]).all()


def test_any_set_of_agents_steps_alone_to_the_whole_networks_numbers():
    """Agent i's next state is drawn by its own keyed number: agents {1, 3} stepped alone, given every state, are the
    whole network's columns 1 and 3, bit for bit."""
    mdp = random_networked(topologies.ring(6).edges, 6, n_states=3, seed=2)
    rng = np.random.default_rng(0)
    s, a, keys = rng.integers(0, 3, (4, 6)), rng.integers(0, 2, (4, 6)), seed_keys(5, range(4))
    whole, part = mdp.step(s, a, keys, 11), mdp.step(s, a[:, [1, 3]], keys, 11, agents=[1, 3])
    assert np.array_equal(whole[0][:, [1, 3]], part[0]) and np.array_equal(whole[1][:, [1, 3]], part[1])


def test_an_agents_generated_tables_are_its_own():
    """Agent 2 on a ring of 8 and of 40 (a neighbourhood of 3 in both): the same tables and rewards, drawn by its id."""
    small, large = (random_networked(topologies.ring(n).edges, n, seed=9) for n in (8, 40))
    assert np.array_equal(small.P[2], large.P[2]) and np.array_equal(small.R[2], large.R[2])
    assert not np.array_equal(small.P[2], small.P[3])


def test_the_long_run_reward_of_keyed_steps_is_the_joint_tables_exact_j():
    """Uniform local policies on a path of 3 agents: the mean team reward of 64 seeds x 4 000 keyed steps is within 4
    standard errors (of the seeds' means, which are independent) of the exact J of the joint table."""
    mdp = random_networked(topologies.path(3).edges, 3, n_states=2, seed=3)
    exact = team.average_return(mdp.joint(), [np.full((8, 2), 0.5)] * 3)
    B, T = 64, 4_000
    keys, rng = seed_keys(1, range(B)), np.random.default_rng(2)
    s, total = np.zeros((B, 3), dtype=np.int64), np.zeros(B)
    for k in range(T):
        s, r = mdp.step(s, rng.integers(0, 2, (B, 3)), keys, k)
        total += r.mean(axis=1)
    means = total / T
    assert abs(means.mean() - exact) <= 4 * means.std(ddof=1) / np.sqrt(B), (means.mean(), exact)


@pytest.mark.parametrize(
    "change, words",
    [
        ({"P": lambda P: P * 1.5}, "probability distribution"),
        ({"R": lambda R: R * np.nan}, "finite"),
        ({"gamma": lambda g: 1.0}, "gamma"),
        ({"R": lambda R: R[:2]}, "P (N, S^K, A, S)"),
    ],
)
def test_a_malformed_networked_mdp_is_refused_in_words(change, words):
    mdp = random_networked(topologies.ring(3).edges, 3)
    fields = {"neighbourhoods": mdp.neighbourhoods, "P": mdp.P, "R": mdp.R, "gamma": mdp.gamma, "start": mdp.start}
    name, how = next(iter(change.items()))
    fields[name] = how(fields[name])
    with pytest.raises(DgtdInputError, match=words.replace("(", r"\(").replace(")", r"\)").replace("^", r"\^")):
        NetworkedMDP(**fields)


def test_a_joint_table_too_large_is_refused():
    with pytest.raises(DgtdInputError, match="exact answers need fewer agents"):
        random_networked(topologies.ring(12).edges, 12).joint()


def test_a_critic_truncated_to_kappa_hops_errs_less_than_qu_et_als_bound_and_none_beyond_the_graph():
    """A path of 6 agents, 2 states and 2 actions each, gamma 0.7, uniform local policies: every agent's largest
    error |Q_i - Q_i truncated to kappa hops| is within rbar gamma^(kappa+1) / (1 - gamma), falls with kappa
    (measured, the largest over agents: 0.24, 0.061, 0.0052, 4.8e-4, 2.8e-5, 0), and is 0 (to rounding) once every
    agent is within kappa hops."""
    from dgtd.problems.networked import hops, truncation_bound, truncation_errors

    mdp = random_networked(topologies.path(6).edges, 6, n_states=2, n_actions=2, gamma=0.7, seed=0)
    errors = truncation_errors(mdp, range(6))
    assert (errors <= truncation_bound(mdp, np.arange(6))[None, :]).all()
    assert (np.diff(errors.max(axis=0)) < 0).all()
    reach = hops(mdp).max(axis=1)  # each agent's eccentricity
    for i in range(6):
        assert np.abs(errors[i, reach[i] :]).max() < 1e-12
        assert errors[i, reach[i] - 1] > 1e-6
