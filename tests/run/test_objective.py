"""What the learners ascend and what is reported are the same objective (`dgtd.run.learn.LearnSettings.objective`):
the long-run average with differential critics (the default), or the normalised discounted return; the exact J, J*
and critic targets of each against closed forms; the actors' warm-up and the two timescales' line."""

from __future__ import annotations

import dataclasses
import itertools
import json

import numpy as np
import pytest

from dgtd.algorithms import make_algorithm
from dgtd.algorithms.actor import SoftmaxActor, timescales
from dgtd.graphs import topologies
from dgtd.graphs.random import random_edges
from dgtd.problems import team
from dgtd.run.learn import LearnSettings, _critic_error, learn, local_policies
from tests.helpers import one_line_error
from tests.run.test_learn import as_joint_table


def random_policies(mdp, rng) -> list:
    return [rng.dirichlet(np.ones(n), size=mdp.n_states) for n in mdp.actions]


def test_the_discounted_return_is_the_discounted_series_from_the_start():
    """J_gamma(pi) = (1 - gamma) sum_t gamma^t start^T P_pi^t rbar_pi, summed here for 400 terms (gamma^400 < 1e-120:
    the tail is below rounding)."""
    mdp = team.pull_away(3, 4, gamma=0.5)
    policies = random_policies(mdp, np.random.default_rng(0))
    P_pi, R_pi = mdp.chain(policies)
    x, total = mdp.start.copy(), 0.0
    for t in range(400):
        total += mdp.gamma**t * x @ R_pi.mean(axis=0)
        x = x @ P_pi
    assert team.discounted_return(mdp, policies) == pytest.approx((1 - mdp.gamma) * total, abs=1e-14)


def test_the_best_discounted_return_is_the_best_deterministic_joint_policys():
    """J*_gamma by value iteration equals the largest J_gamma over all 4^3 deterministic joint policies of a 2-agent,
    3-state team MDP (an optimal policy is deterministic and stationary), to 1e-10; and the optimal joint actions'
    policy attains it."""
    mdp = team.pull_away(2, 3, gamma=0.7, seed=4)
    mdp = dataclasses.replace(mdp, R=np.random.default_rng(1).uniform(0, 1, mdp.R.shape))
    best = -np.inf
    for joint in itertools.product(range(4), repeat=3):
        local = mdp.local(np.array(joint))  # (S, N)
        policies = [np.eye(2)[local[:, i]] for i in range(2)]
        best = max(best, team.discounted_return(mdp, policies))
    J, action = mdp.best_discounted()
    assert J == pytest.approx(best, abs=1e-10)
    local = mdp.local(action)
    assert team.discounted_return(mdp, [np.eye(2)[local[:, i]] for i in range(2)]) == pytest.approx(best, abs=1e-10)


def test_a_factored_mdps_best_discounted_return_is_its_joint_tables():
    f = team.factored(6, 4, 2, seed=3)
    assert f.best_discounted()[0] == pytest.approx(as_joint_table(f).best_discounted()[0], abs=1e-10)


def test_the_differential_critics_target_solves_the_poisson_equation():
    """Under the average objective the critics' target on tabular features is a differential value function:
    (I - P_pi) Phi w* = rbar_pi - J(pi) 1, to 1e-12; and the critics' error does not see a constant added to every
    agent's values (the differential values are defined up to one)."""
    mdp = team.pull_away(3, 5, seed=2)
    mdp = dataclasses.replace(mdp, R=np.random.default_rng(3).uniform(0, 1, mdp.R.shape))
    policies = random_policies(mdp, np.random.default_rng(5))
    P_pi, R_pi = mdp.chain(policies)
    w = team.critic_target(mdp, policies, "average")
    J = team.average_return(mdp, policies)
    assert np.abs((np.eye(5) - P_pi) @ mdp.Phi @ w - (R_pi.mean(axis=0) - J)).max() < 1e-12
    W = w[None, :] + np.random.default_rng(6).normal(0, 0.1, (3, 5))
    moved = W + 7.0  # (Phi = I: adding 7 to every weight adds 7 to every value)
    assert _critic_error(mdp, policies, moved, "state", "average") == pytest.approx(
        _critic_error(mdp, policies, W, "state", "average"), rel=1e-12
    )
    assert _critic_error(mdp, policies, np.tile(w, (3, 1)), "state", "average") < 1e-24


CASES = [
    {"actor": "networked"},
    {"actor": "independent"},
    {"actor": "centralised", "batch": 3},
    {"actor": "networked", "values": "action"},
]


@pytest.mark.parametrize("case", CASES)
def test_average_objective_learners_on_numpy_and_numba_agree(case):
    """The differential critics' arithmetic (the running averages mu_i, mu~_i of `dgtd.run.learn.objective_terms`)
    on the compiled backend: the NumPy run's policies and critics to 1e-12."""
    mdp, net = team.pull_away(), random_edges(topologies.ring(4), 0.8)
    runs = [
        learn(mdp, net, make_algorithm("dgtd", alpha0=1.0, beta=100.0), SoftmaxActor(warmup=100),
              LearnSettings(iterations=600, seeds=2, checkpoints=2, backend=backend, **case))
        for backend in ("numpy", "numba")
    ]  # fmt: skip
    assert np.abs(runs[0].policies - runs[1].policies).max() < 1e-12
    assert np.abs(runs[0].critic - runs[1].critic).max() < 1e-12
    assert np.array_equal(runs[0].metrics["return"], runs[1].metrics["return"]) or np.allclose(
        runs[0].metrics["return"], runs[1].metrics["return"], atol=1e-12, rtol=0
    )


def delayed_run(objective: str, actor: SoftmaxActor, learners: str):
    mdp = team.delayed_reward()
    settings = LearnSettings(iterations=20_000, seeds=4, checkpoints=2, actor=learners, objective=objective)
    return mdp, learn(mdp, random_edges(topologies.ring(2), 1.0), make_algorithm("dgtd", alpha0=1.0, beta=100.0),
                      actor, settings)  # fmt: skip


@pytest.mark.parametrize("learners", ["networked", "centralised"])
def test_a_delayed_reward_is_found_under_the_average_objective(learners):
    """delayed-reward (two agents must advance together 4 times to earn 3, else 0.3 a step; J* = 0.75): with the
    default steps and warm-up every seed's long-run average ends within 5 % of J* (measured 0.745-0.747 over 4
    seeds); without the warm-up the actors commit to the small reward before the critics have met the prize (measured
    0.30 in every seed); under the discounted objective (gamma 1/2) the best policy stays in state 0, whose long-run
    average is 0.3."""
    mdp, run = delayed_run("average", SoftmaxActor(), learners)
    assert run.return_best == pytest.approx(0.75, abs=1e-9)
    assert run.metrics["return"][-1].min() >= 0.95 * 0.75
    _, hasty = delayed_run("average", SoftmaxActor(warmup=0), learners)
    assert hasty.metrics["return"][-1].max() < 0.35
    _, discounted = delayed_run("discounted", SoftmaxActor(), learners)
    averages = [team.average_return(mdp, local_policies(mdp, pi)) for pi in discounted.policies]
    assert max(averages) < 0.35 and discounted.return_best == pytest.approx(mdp.best_discounted()[0], abs=1e-12)


def test_the_two_timescales_line_says_where_the_actor_is_the_faster():
    """The default steps: the actor holds still for 2 000 steps of 20 000, then its step beta_2000 = 0.5 / 3^0.8 is
    sqrt(2100) 0.5 / 3^0.8 = 9.5 times the critic's 1 / sqrt(2100), the larger until about 9.9 million steps; steps
    under which the critic's is the larger throughout say nothing."""
    critic = make_algorithm("dgtd", alpha0=1.0, beta=100.0)
    said = timescales(SoftmaxActor(), critic, 20_000)
    ratio = 0.5 / 3**0.8 * np.sqrt(2100)
    assert f"up to {ratio:.3g} times" in said and "until step 9.8" in said
    assert timescales(SoftmaxActor(step=0.05), critic, 20_000) == ""
    assert SoftmaxActor().held_for(20_000) == 2000 and SoftmaxActor().held_for(5000) == 500
    assert SoftmaxActor(warmup=7).steps(0, 10)[:7].max() == 0.0 and SoftmaxActor(warmup=7).steps(0, 10)[7] > 0


def test_the_objective_is_chosen_recorded_and_said(run_cli, tmp_path):
    """`dgtd learn --objective discounted`: the header and summary.json say which objective J and J* are of, and
    return_last is the discounted return of policy_last; --gamma in a simulator under the average objective (whose
    critics are not discounted) is one line."""
    code, out, err = run_cli("learn", "pull-away", "-T", 300, "--objective", "discounted", "--no-progress",
                             "--no-plots", "--out", tmp_path / "d")  # fmt: skip
    assert code == 0, err
    assert "objective: the discounted team return at gamma 0.5" in out
    summary = json.loads((tmp_path / "d" / "summary.json").read_text())
    mdp = team.pull_away()
    assert summary["objective"] == "discounted"
    policies = [np.asarray(p) for p in summary["policy_last"][0]]
    assert summary["return_last"][0] == pytest.approx(team.discounted_return(mdp, policies), abs=1e-12)
    assert summary["return_best"] == pytest.approx(mdp.best_discounted()[0], abs=1e-12)
    one_line_error(*run_cli("learn", "mpe-spread", "--gamma", 0.9, "-T", 10, "--out", tmp_path / "e"),
                   "--objective discounted")  # fmt: skip
    one_line_error(*run_cli("learn", "pull-away", "--objective", "total", "--out", tmp_path / "f"), "objective")


def test_independent_learners_critic_error_is_against_the_critic_they_learn():
    """An independent learner's critic learns its own reward's values, not the team's: its error is measured against
    that target (measured 0.004 at the end on pull-away; against the team's critic it read 0.9 and rose as the
    agents converged)."""
    mdp, net = team.pull_away(), random_edges(topologies.ring(4), 0.8)
    result = learn(mdp, net, make_algorithm("dgtd", alpha0=1.0, beta=100.0), SoftmaxActor(),
                   LearnSettings(iterations=10_000, seeds=2, checkpoints=2, actor="independent"))  # fmt: skip
    assert result.metrics["critic_error"][-1].max() < 0.02


def test_a_diverged_learners_seeds_are_nan_not_a_traceback(run_cli, tmp_path):
    """Critics at steps 1000/sqrt(k+100) diverge within 600 steps of 3 000: every metric of the diverged checkpoints
    is NaN (the exact measures raised LinAlgError on NaN policies) and summary.json's return_last null; every seed
    having diverged by the second checkpoint, the run stops there and says so."""
    code, out, err = run_cli("learn", "pull-away", "--algorithm", "consensus-td0", "--alpha0", 1000, "-T", 3000,
                             "--checkpoints", 10, "--backend", "numpy", "--no-progress", "--no-plots",
                             "--out", tmp_path / "d")  # fmt: skip
    assert code == 0, err
    summary = json.loads((tmp_path / "d" / "summary.json").read_text())
    assert summary["return_last"] == [None, None]
    assert "nan" in out
    assert summary["diverged_at"] == [600, 600] and "the run stopped at step 600" in err  # (of 3 000)
    rows = (tmp_path / "d" / "metrics.csv").read_text().splitlines()[1:]
    assert all(row.endswith(",nan") for row in rows if row.split(",")[3] == "return" and int(row.split(",")[2]) >= 600)


def test_the_entropy_bonus_follows_the_entropys_gradient():
    """E_{a ~ pi}[psi(a) (-log pi(a))] = grad_theta H(softmax(theta)), checked against central differences of H on a
    random row (to 1e-8), so that an actor with bonus tau ascends J + tau H."""
    from dgtd.algorithms.actor import policy, score_step

    theta = np.random.default_rng(2).normal(size=5)
    pi = policy(theta)
    expected = sum(pi[a] * score_step(1.0, 0.0, np.log(pi[a]), 1.0, np.eye(5)[a], pi) for a in range(5))

    def H(t):
        p = policy(t)
        return -(p * np.log(p)).sum()

    numeric = np.array([(H(theta + 1e-5 * e) - H(theta - 1e-5 * e)) / 2e-5 for e in np.eye(5)])
    assert np.abs(expected - numeric).max() < 1e-8


def test_an_entropy_bonus_keeps_the_policies_wider_on_numpy_and_numba_alike():
    """pull-away, 3 000 steps: with tau = 0.5 the policies' entropy at the end is higher than without (measured), and
    the compiled learners equal the NumPy ones to 1e-12."""
    mdp, net = team.pull_away(), random_edges(topologies.ring(4), 0.8)

    def run(tau, backend):
        return learn(mdp, net, make_algorithm("dgtd", alpha0=1.0, beta=100.0), SoftmaxActor(entropy=tau),
                     LearnSettings(iterations=3000, seeds=2, checkpoints=2, backend=backend))  # fmt: skip

    plain, wide, compiled = run(0.0, "numba"), run(0.5, "numpy"), run(0.5, "numba")
    assert wide.metrics["entropy"][-1].min() > plain.metrics["entropy"][-1].max()
    assert np.abs(wide.policies - compiled.policies).max() < 1e-12


@pytest.mark.parametrize("objective", ["average", "discounted"])
def test_every_agents_critic_target_at_once_is_each_agents_own(objective):
    """`critic_targets` solves one chain with a right-hand side each (the independent learners' critic error at
    10 000 agents took 180 s a checkpoint, one chain an agent, and takes a second): equal to `critic_target` agent by
    agent and for the team's reward, on random policies of pull-away and of a factored task (1e-12)."""
    rng = np.random.default_rng(7)
    for mdp in (team.pull_away(), team.factored(6)):
        policies = [rng.dirichlet(np.ones(n), size=mdp.n_states) for n in mdp.actions]
        agents = [None, *range(mdp.n_agents)]
        together = team.critic_targets(mdp, policies, objective, agents)
        P, R = mdp.chain(policies)
        d, Phi = team.long_run(P, mdp.start), mdp.Phi
        gamma = mdp.gamma if objective == "discounted" else 1.0
        A = Phi.T @ np.diag(d) @ (np.eye(mdp.n_states) - gamma * P) @ Phi
        for row, agent in zip(together, agents):
            r = R.mean(axis=0) if agent is None else R[agent]
            r = r if objective == "discounted" else r - d @ r
            expected = np.linalg.pinv(A) @ (Phi.T @ (d * r))  # (the least-norm solution, as the target's)
            np.testing.assert_allclose(row, expected, rtol=1e-10, atol=1e-10)
            np.testing.assert_allclose(row, team.critic_target(mdp, policies, objective, agent), rtol=1e-12, atol=1e-12)
