"""Agents that learn their policies (`dgtd learn`, `dgtd.run.learn`): on a team MDP whose local rewards pull every
agent away from the team's best joint action, networked learners with a distributed critic find it, independent
learners do not, centralised ones do; the exact answers are checked against linear algebra written here; the numbers
are keyed (a seed's are its own) and bad input is one line."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers import one_line_error

from dgtd.algorithms import make_algorithm
from dgtd.algorithms.actor import SoftmaxActor
from dgtd.graphs import topologies
from dgtd.graphs.random import random_edges
from dgtd.problems import team
from dgtd.run.learn import LearnSettings, learn

BUDGET = 10_000  # steps: DGTD's networked learners pass 0.9 on every agent's best action by 7 000 (measured 0.952)


def run(actor: str, critic: str = "dgtd", seeds: int = 2, iterations: int = BUDGET, **kw):
    mdp = team.pull_away()
    net = random_edges(topologies.ring(4), 0.8)
    settings = LearnSettings(iterations=iterations, seeds=seeds, actor=actor, checkpoints=4)
    return learn(mdp, net, make_algorithm(critic, alpha0=1.0, beta=100.0), SoftmaxActor(), settings, **kw)


@pytest.mark.parametrize("actor, reaches", [("networked", True), ("independent", False), ("centralised", True)])
def test_only_learners_of_the_teams_reward_find_its_best_joint_action(actor, reaches):
    """Within 10 000 steps, 2 seeds, links up with probability 0.8: networked (DGTD critic, the team's reward by
    consensus) and centralised learners put at least 0.9 on their part of the team's best action in every state
    (measured 0.97 and 0.99); independent ones, which each learn their own reward, put at most 0.1 on it (measured
    0.0), and their return is the all-deviate one, J = 1 of J* = 2."""
    result = run(actor)
    least = result.metrics["best_probability"][:, -1]
    if reaches:
        assert least.min() >= 0.9, least
        assert result.metrics["return"][:, -1].min() > 1.95
    else:
        assert least.max() <= 0.1, least
        assert result.metrics["return"][:, -1].max() < 1.1
    assert result.return_best == pytest.approx(2.0, abs=1e-9)


def exact_return(mdp, policies) -> float:
    """J = d^T rbar_pi written out: the joint policy as the product of the local ones over every joint action, the
    chain P_pi, its stationary d as the eigenvector of P_pi^T for eigenvalue 1."""
    S, A = mdp.n_states, mdp.P.shape[1]
    pi = np.ones((S, A))
    for joint in range(A):
        for i, a in enumerate(np.unravel_index(joint, mdp.actions)):
            pi[:, joint] *= np.asarray(policies[i])[:, a]
    P_pi = np.einsum("sa,sat->st", pi, mdp.P)
    values, vectors = np.linalg.eig(P_pi.T)
    d = np.real(vectors[:, np.argmin(np.abs(values - 1.0))])
    d /= d.sum()
    return float(d @ np.einsum("sa,sa->s", pi, mdp.R.mean(axis=0)))


def test_dgtd_learn_writes_the_last_policies_and_their_exact_return(run_cli, tmp_path):
    """`dgtd learn pull-away`: summary.json holds policy_last ([seeds][agents] arrays (S, A_i)), return_last equal to
    the exact J of those very policies (1e-12, by the linear algebra above), and return_best J* = 2."""
    code, text, err = run_cli(
        "learn", "pull-away", "-T", 2000, "--seeds", 2, "--no-progress", "--no-plots", "--out", tmp_path
    )
    assert code == 0, err
    s = json.loads((tmp_path / "summary.json").read_text())
    mdp = team.pull_away()
    assert np.shape(s["policy_last"]) == (2, 4, 3, 2)
    for b in range(2):
        assert s["return_last"][b] == pytest.approx(exact_return(mdp, s["policy_last"][b]), abs=1e-12)
    assert s["return_best"] == pytest.approx(2.0, abs=1e-9)
    assert "exact return J of the last policies" in text and (tmp_path / "metrics.csv").read_text().count("\n") > 8


def test_a_seeds_numbers_are_its_own():
    """Every random number is keyed by (seed, purpose, agent, step): seed 0 of a 2-seed run is a 1-seed run, bit for
    bit, and the same run twice is the same."""
    one, two = run("networked", seeds=1, iterations=600), run("networked", seeds=2, iterations=600)
    assert np.array_equal(one.policies[0], two.policies[0]) and np.array_equal(one.critic[0], two.critic[0])
    assert np.array_equal(two.policies, run("networked", seeds=2, iterations=600).policies)


def test_lost_messages_are_counted_and_the_critics_messages_carry_the_team_estimate():
    """Over links that lose 30 % of messages, fewer arrive (counted), and the learners still improve their return."""
    from dgtd.channels import Arcs, Lossy

    arcs = Arcs.of(topologies.ring(4).edges, 4)
    perfect, lossy = (
        run("networked", iterations=1500),
        run("networked", iterations=1500, channel=Lossy(np.full(arcs.n_arcs, 0.3))),
    )
    assert 0.6 < lossy.messages.sum() / perfect.messages.sum() < 0.8
    assert lossy.metrics["return"][:, -1].min() > lossy.metrics["return"][:, 0].min() - 0.05


@pytest.mark.parametrize(
    "args, words",
    [
        (["pull-away", "--actor-power", "0.4"], ["faster than the critic's", "above 0.5"]),
        (["no-such-task"], ["name a learning task", "pull-away"]),
        (["pull-away", "--actor", "lonely"], ["lonely"]),
        (["pull-away", "--agents", "1"], ["at least 2 agents"]),
    ],
)
def test_bad_learning_input_is_one_line(run_cli, tmp_path, args, words):
    one_line_error(*run_cli("learn", *args, "-T", 10, "--no-progress", "--out", tmp_path / "o"), *words)
