"""Agents that learn their policies (`dgtd learn`, `dgtd.run.learn`): on a team MDP whose local rewards pull every
agent away from the team's best joint action, networked learners with a distributed critic find it, independent
learners do not, centralised ones do; the exact answers are checked against linear algebra written here; the numbers
are keyed (a seed's are its own) and bad input is one line."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers import one_line_error
from numpy.testing import assert_allclose

from dgtd.algorithms import make_algorithm
from dgtd.algorithms.actor import SoftmaxActor
from dgtd.errors import DgtdInputError
from dgtd.graphs import topologies
from dgtd.graphs.random import random_edges
from dgtd.problems import team
from dgtd.run.learn import LearnSettings, learn

BUDGET = 10_000  # steps of a learning run here
# steps and seeds within which networked learners with the DGTD critic put 0.9 on the team's best action: 4 seeds at
# 10 000 steps measured 0.982, 0.988, 0.715 (still climbing), 0.992; at 20 000: 0.993, 0.994, 0.992, 0.995
REACH, REACH_SEEDS = 20_000, 4


def run(
    actor: str,
    critic: str = "dgtd",
    seeds: int = 2,
    iterations: int = BUDGET,
    batch: int = 1,
    values: str = "state",
    backend: str = "numba",
    **kw,
):
    mdp = team.pull_away()
    net = random_edges(topologies.ring(4), 0.8)
    settings = LearnSettings(
        iterations=iterations, seeds=seeds, actor=actor, checkpoints=4, batch=batch, values=values, backend=backend
    )
    actor_steps = SoftmaxActor(step=0.1) if values == "action" else SoftmaxActor()
    return learn(mdp, net, make_algorithm(critic, alpha0=1.0, beta=100.0), actor_steps, settings, **kw)


@pytest.mark.parametrize(
    "critic, actor, values, batch, loss",
    [
        ("dgtd", "networked", "state", 1, 0.0),
        ("dgtd", "networked", "action", 1, 0.0),
        ("consensus-td0", "independent", "state", 1, 0.0),
        ("consensus-tdrc", "centralised", "state", 1, 0.3),
        ("td-tracking", "networked", "state", 5, 0.3),
        ("tdc-tracking", "networked", "state", 1, 0.0),
        ("pd-td", "networked", "state", 1, 0.0),
        ("local", "networked", "action", 2, 0.0),
    ],
)
def test_compiled_and_jax_learners_are_the_numpy_learners(critic, actor, values, batch, loss):
    """`--backend numba` (`dgtd.backends.compiled.learner`) runs the NumPy learners' arithmetic per agent, summed in
    another order (dot products in two accumulators, the Metropolis mix over the arcs heard rather than a dense
    matrix): a few units of rounding (1e-16) a step, which these runs, whose critics converge, do not grow (measured
    at most 5e-16 after 600 steps); `--backend jax` (`dgtd.backends.jax_learner`) runs the very functions NumPy runs,
    compiled by XLA (measured at most 5e-16 too). 1e-12 on the policies, the critics and every metric, relative to
    1 + |x|."""
    from dgtd.channels import Arcs, Lossy

    pytest.importorskip("jax")
    arcs = Arcs.of(random_edges(topologies.ring(4), 0.8).base.edges, 4)
    channel = None if loss == 0 else Lossy(np.full(arcs.n_arcs, loss))
    numpy, *others = (
        run(actor, critic, iterations=600, batch=batch, values=values, backend=b, channel=channel)
        for b in ("numpy", "numba", "jax")
    )
    close = lambda x, y: np.testing.assert_array_less(np.abs(x - y) / (1 + np.abs(x)), 1e-12)  # noqa: E731
    for other in others:
        close(numpy.policies, other.policies)
        close(numpy.critic, other.critic)
        for name, values_ in numpy.metrics.items():
            finite = np.isfinite(values_)
            assert (finite == np.isfinite(other.metrics[name])).all()
            close(values_[finite], other.metrics[name][finite])


@pytest.mark.parametrize("actor, reaches", [("networked", True), ("independent", False), ("centralised", True)])
def test_only_learners_of_the_teams_reward_find_its_best_joint_action(actor, reaches):
    """Within 20 000 steps, 4 seeds, links up with probability 0.8: networked (DGTD critic, the team's reward by
    consensus) and centralised learners put at least 0.9 on their part of the team's best action in every state
    (measured at least 0.992 and 0.994); independent ones, which each learn their own reward, put at most 0.1 on it
    (measured 0.0), and their return is the all-deviate one, J = 1 of J* = 2."""
    result = run(actor, seeds=REACH_SEEDS, iterations=REACH)
    least = result.metrics["best_probability"][-1]
    if reaches:
        assert least.min() >= 0.9, least
        assert result.metrics["return"][-1].min() > 1.95
    else:
        assert least.max() <= 0.1, least
        assert result.metrics["return"][-1].max() < 1.1
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


def test_many_agents_policies_are_in_policies_npz_alone(run_cli, tmp_path, monkeypatch):
    """Beyond `POLICY_JSON` numbers (seeds x agents x states x actions: 200 000, a JSON text of tens of megabytes at
    40 000 agents, the largest thing rank 0 held) summary.json's policy_last is null and the policies are those of
    policies.npz, whose last J return_last still is."""
    import dgtd.run.learn as learning

    monkeypatch.setattr(learning, "POLICY_JSON", 47)  # pull-away's 2 x 4 x 3 x 2 = 48 numbers
    code, _, err = run_cli("learn", "pull-away", "-T", 200, "--no-progress", "--no-plots", "--out", tmp_path)
    assert code == 0, err
    s = json.loads((tmp_path / "summary.json").read_text())
    policies = np.load(tmp_path / "policies.npz")["policies"]
    assert s["policy_last"] is None and policies.shape == (2, 4, 3, 2)
    assert s["return_last"][1] == pytest.approx(exact_return(team.pull_away(), policies[1]), abs=1e-12)


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
    assert lossy.metrics["return"][-1].min() > lossy.metrics["return"][0].min() - 0.05


@pytest.mark.parametrize(
    "args, words",
    [
        (["pull-away", "--actor-power", "0.4"], ["faster than the critic's", "above 0.5"]),
        (["no-such-task"], ["name a learning task", "pull-away"]),
        (["pull-away", "--actor", "lonely"], ["lonely"]),
        (["pull-away", "--agents", "1"], ["at least 2 agents"]),
        (["pull-away", "--backend", "jax", "--delay", "1"], ["jax runs perfect and lossy links", "1 steps late"]),
        (["pull-away", "--gamma", "0.9"], ["gamma", "pull-away", "its own (0.5)"]),  # it ran at 0.5, recording 0.9
    ],
)
def test_bad_learning_input_is_one_line(run_cli, tmp_path, args, words):
    one_line_error(*run_cli("learn", *args, "-T", 10, "--no-progress", "--out", tmp_path / "o"), *words)


def as_joint_table(f: team.FactoredMDP) -> team.TeamMDP:
    """A small factored MDP's joint table, built here from its definition: P(s, a, s') = (1/G) sum_g P_g(s, a_g, s'),
    R_i(s, a) = R_i(s, a_i)."""
    N, S = f.n_agents, f.n_states
    A = 2**N
    a = np.stack(np.unravel_index(np.arange(A), (2,) * N), axis=-1)
    P = np.zeros((S, A, S))
    for j in range(A):
        for g, members in enumerate(f.groups):
            P[:, j, :] += f.Pg[g, :, np.ravel_multi_index(tuple(a[j, members]), (2,) * len(members)), :] / len(f.groups)
    R = np.stack([f.R[i][:, a[:, i]] for i in range(N)])
    return team.team_mdp(P, R, f.Phi, f.gamma, (2,) * N)


def test_a_factored_mdps_exact_answers_are_its_joint_tables():
    """J(pi), the critic's target and J* of a factored MDP (6 agents in groups of 2, 4 states), computed without the
    joint table, equal those of the table built from its definition (1e-12; J* by relative value iteration over the
    64 joint actions)."""
    f = team.factored(6, 4, 2, seed=3)
    joint = as_joint_table(f)
    rng = np.random.default_rng(0)
    policies = [rng.dirichlet(np.ones(2), size=4) for _ in range(6)]
    assert team.average_return(f, policies) == pytest.approx(team.average_return(joint, policies), abs=1e-12)
    assert np.allclose(team.critic_target(f, policies), team.critic_target(joint, policies), atol=1e-10)
    assert f.best_return()[0] == pytest.approx(joint.best_return()[0], abs=1e-9)


def test_a_factored_mdps_steps_follow_its_transitions():
    """200 000 steps drawn by `FactoredMDP.step` from one state and joint action: the frequency of every next state
    within 5 standard errors of P(s, a, .) of the joint table (a false alarm once in 1.7 million per state)."""
    f = team.factored(4, 3, 2, seed=1)
    joint = as_joint_table(f)
    rng = np.random.default_rng(7)
    n = 200_000
    s, a = np.full(n, 1), np.tile([1, 0, 0, 1], (n, 1))
    s_next, r = f.step(s, a, (rng.random(n), rng.random(n)))
    p = joint.P[1, joint.joint(np.array([1, 0, 0, 1]))]
    freq = np.bincount(s_next, minlength=3) / n
    assert np.all(np.abs(freq - p) <= 5 * np.sqrt(p * (1 - p) / n) + 1e-12), (freq, p)
    assert np.array_equal(r[0], [f.R[i, 1, a[0, i]] for i in range(4)])


def test_a_thousand_agents_learn_on_a_factored_problem():
    """1 000 agents in groups of 2, 10 states, links of a ring up with probability 0.8: 1 500 steps of learners of
    their own reward raise the exact return (measured 2.551 -> 2.607 of J* = 2.667 in 2 000 steps)."""
    mdp = team.factored(1000)
    net = random_edges(topologies.ring(1000), 0.8)
    settings = LearnSettings(iterations=1500, seeds=1, actor="independent", checkpoints=3)
    result = learn(mdp, net, make_algorithm("dgtd", alpha0=1.0, beta=100.0), SoftmaxActor(), settings)
    J = result.metrics["return"][:, 0]  # (checkpoints, seeds): the one seed's
    assert J[-1] > J[0] + 0.02 and J[-1] < result.return_best


@pytest.mark.parametrize("actor", ["networked", "independent"])
def test_a_learning_run_resumed_from_a_checkpoint_ends_with_the_uninterrupted_numbers(actor, tmp_path):
    """Checkpoints every 400 steps of 1 300 (a block of draws is 512: the resumed step falls inside one); resumed from
    the second, through the run's checkpoint file (`dgtd.run.checkpoint`, as the command line keeps it), the run ends
    with the uninterrupted run's policies, critics and metrics, bit for bit, over links that lose 20 % of messages."""
    from dgtd.channels import Arcs, Lossy
    from dgtd.run.checkpoint import load_checkpoint, save_checkpoint

    mdp = team.pull_away()
    net = random_edges(topologies.ring(4), 0.8)
    channel = Lossy(np.full(Arcs.of(topologies.ring(4).edges, 4).n_arcs, 0.2))
    settings = LearnSettings(iterations=1300, seeds=2, actor=actor, checkpoints=5)
    critic = make_algorithm("dgtd", alpha0=1.0, beta=100.0)
    snaps = []
    whole = learn(mdp, net, critic, SoftmaxActor(), settings, channel, checkpoint_every=400, on_checkpoint=snaps.append)
    assert [int(s["k"]) for s in snaps] == [400, 800, 1200, 1300]  # (and at T: a finished run extends from it)
    save_checkpoint(tmp_path / "c.npz", snaps[1], {"seed": 0})
    resumed = learn(mdp, net, critic, SoftmaxActor(), settings, channel, resume=load_checkpoint(tmp_path / "c.npz")[0])
    assert np.array_equal(whole.policies, resumed.policies) and np.array_equal(whole.critic, resumed.critic)
    for name, values in whole.metrics.items():
        assert np.array_equal(values, resumed.metrics[name], equal_nan=True), name
    assert np.array_equal(whole.bits, resumed.bits)


def test_dgtd_learn_killed_after_a_checkpoint_resumes_to_the_uninterrupted_numbers(run_cli, tmp_path, monkeypatch):
    """`dgtd learn --checkpoint-every 300` cut off after its second checkpoint (as a kill would), then the same
    command again: "resuming", and summary.json's policies and metrics.csv byte for byte the uninterrupted run's."""
    import dgtd.cli.learn as cli_learn

    command = (
        "learn",
        "pull-away",
        "-T",
        1000,
        "--loss",
        "0.2",
        "--no-progress",
        "--no-plots",
        "--checkpoint-every",
        300,
    )
    code, _, err = run_cli(*command, "--out", tmp_path / "whole")
    assert code == 0, err
    kept = []
    keep = cli_learn._keep

    def cut_after_two(out, snap, record):
        keep(out, snap, record)
        kept.append(int(snap["k"]))
        if len(kept) == 2:
            raise KeyboardInterrupt

    monkeypatch.setattr(cli_learn, "_keep", cut_after_two)
    code, _, _ = run_cli(*command, "--out", tmp_path / "cut")
    assert code != 0 and kept == [300, 600] and (tmp_path / "cut" / "learning-checkpoint.npz").exists()
    monkeypatch.setattr(cli_learn, "_keep", keep)
    other = run_cli(*command, "--seed", 3, "--out", tmp_path / "cut")  # the refusal says which setting differs
    one_line_error(*other, "checkpoint of another learning run (seed = None there, 3 here)")
    code, text, err = run_cli(*command, "--out", tmp_path / "cut")
    assert code == 0 and "resuming" in text, err
    for name in ("metrics.csv",):
        assert (tmp_path / "cut" / name).read_bytes() == (tmp_path / "whole" / name).read_bytes()
    whole, cut = (json.loads((tmp_path / d / "summary.json").read_text()) for d in ("whole", "cut"))
    assert whole["policy_last"] == cut["policy_last"]
    from dgtd.run.checkpoint import load_checkpoint

    assert load_checkpoint(tmp_path / "cut" / "learning-checkpoint.npz")[0]["k"] == 1000  # (its state at the end)


def test_a_problem_file_is_learned_from_its_starting_policies(run_cli, tmp_path):
    """`dgtd learn --problem FILE`: the multi-agent MDP form with one starting policy per agent; the return at the
    first checkpoint is near the starting policies' exact J (they are where the actors start), and a file with
    behaviour policies, or fewer policies than agents, is one line."""
    mdp = team.pull_away()
    start = [np.tile([0.9, 0.1], (3, 1))] * 4  # mostly action 0: the team's in states 0 and 2, not in 1
    arrays = dict(P=mdp.P, R=mdp.R, Phi=mdp.Phi, gamma=mdp.gamma, **{f"policy_{i}": p for i, p in enumerate(start)})
    np.savez(tmp_path / "p.npz", **arrays)
    code, text, err = run_cli(
        "learn", "--problem", tmp_path / "p.npz", "-T", 200, "--checkpoints", 20, "--no-progress", "--no-plots",
        "--out", tmp_path / "o",
    )  # fmt: skip
    assert code == 0, err
    rows = [r.split(",") for r in (tmp_path / "o" / "metrics.csv").read_text().splitlines()[1:]]
    first = [float(r[4]) for r in rows if r[3] == "return" and r[2] == "10"]
    assert abs(np.mean(first) - team.average_return(mdp, start)) < 0.02, (first, team.average_return(mdp, start))
    np.savez(tmp_path / "b.npz", **arrays, behaviour_0=start[0])
    one_line_error(
        *run_cli("learn", "--problem", tmp_path / "b.npz", "--out", tmp_path / "x"), "behaviour_0", "on-policy"
    )
    np.savez(tmp_path / "c.npz", **{k: v for k, v in arrays.items() if k != "policy_3"})
    one_line_error(
        *run_cli("learn", "--problem", tmp_path / "c.npz", "--out", tmp_path / "x"), "3 policies for 4 agents"
    )
    one_line_error(
        *run_cli("learn", "pull-away", "--problem", tmp_path / "p.npz", "--out", tmp_path / "x"), "one learning task"
    )


def test_dgtd_compare_on_a_learning_task_compares_learners(run_cli, tmp_path):
    """`dgtd compare pull-away -a dgtd,consensus-td0`: networked learners with each critic, independent and
    centralised ones, on the same keyed numbers (a networked/dgtd row equals `dgtd learn`'s run); the table names
    the highest return; a centralised critic is refused in one line."""
    common = ("-T", 600, "--seeds", 2, "--no-progress", "--no-plots")
    code, text, err = run_cli("compare", "pull-away", "-a", "dgtd,consensus-td0", *common, "--out", tmp_path / "c")
    assert code == 0, err
    s = json.loads((tmp_path / "c" / "summary.json").read_text())
    labels = {"networked/dgtd", "networked/consensus-td0", "independent/dgtd", "centralised/dgtd"}
    assert labels <= set(s) and "highest return:" in text
    code, _, err = run_cli("learn", "pull-away", *common, "--out", tmp_path / "l")
    assert code == 0, err
    alone = sorted(json.loads((tmp_path / "l" / "summary.json").read_text())["return_last"])
    assert alone == [s["networked/dgtd"]["return_last"][k] for k in ("min", "max")]  # 2 seeds: the same two numbers
    one_line_error(*run_cli("compare", "pull-away", "-a", "td0", *common, "--out", tmp_path / "x"), "distributed")


def test_mini_batches_send_once_a_round():
    """`batch` M (Chen et al.'s mini-batches): the agents communicate and move once every M steps, by the mean of the
    round's samples; M = 5 delivers a fifth of the messages of M = 1 (up to which links were up at the rounds'
    steps), and M = 1 is the step-by-step run, bit for bit. Checkpoints must fall at a round's end."""
    one, five = run("networked", iterations=1000), run("networked", iterations=1000, batch=5)
    assert 0.17 < five.messages.sum() / one.messages.sum() < 0.23
    mdp, net = team.pull_away(), random_edges(topologies.ring(4), 0.8)
    with pytest.raises(DgtdInputError, match="multiple of the --batch 5"):
        learn(
            mdp, net, make_algorithm("dgtd"), SoftmaxActor(), LearnSettings(iterations=100, batch=5), checkpoint_every=7
        )


@pytest.mark.parametrize("actor, reaches", [("networked", True), ("independent", False)])
def test_an_action_value_critic_finds_the_teams_best_action_too(actor, reaches):
    """Zhang et al.'s Algorithm 1 (`values="action"`): each agent's DGTD critic evaluates the team's action values on
    the additive features f(s, a) by expected SARSA, the advantage is agent i's own block of them, no reward
    estimate is sent. Actor steps 0.1 (the default for action values): within 10 000 steps networked learners put at
    least 0.9 on the team's best action (measured 0.955, 0.973), independent ones at most 0.1 (measured 0.003); the
    critics' error against the exact expected-SARSA fixed point ends below 1e-2 (in values). Discounted critics, as
    the measured numbers were (the average objective's: tests/run/test_objective.py)."""
    mdp = team.pull_away()
    net = random_edges(topologies.ring(4), 0.8)
    settings = LearnSettings(
        iterations=BUDGET, seeds=2, actor=actor, checkpoints=4, values="action", objective="discounted"
    )
    result = learn(mdp, net, make_algorithm("dgtd", alpha0=1.0, beta=100.0), SoftmaxActor(step=0.1), settings)
    least = result.metrics["best_probability"][-1]
    assert (least.min() >= 0.9) if reaches else (least.max() <= 0.1), least
    if reaches:
        assert result.metrics["critic_error"][-1].max() < 1e-2


def test_the_exact_action_values_of_uniform_policies_on_pull_away():
    """Under uniform policies every state's team reward averages 1.5, so V = 1.5 / (1 - 1/2) = 3 everywhere and
    Q(s, a) = rbar(s, a) + 3 / 2 = 3.5 - #deviators / 4, which the additive features hold exactly: the expected-SARSA
    fixed point `action_critic_target` gives it (1e-12)."""
    mdp = team.pull_away()
    Phi_Q, d, w = team.action_critic_target(mdp, [np.full((3, 2), 0.5)] * 4)
    pairs = np.arange(3 * 16)
    s, a = pairs // 16, mdp.local(pairs % 16)
    deviators = (a != (s % 2)[:, None]).sum(axis=1)
    assert np.allclose(Phi_Q @ w, 3.5 - deviators / 4, atol=1e-12) and d.sum() == pytest.approx(1.0)


def test_learners_over_links_that_hold_copies_run_on_numpy_and_say_so(run_cli, tmp_path):
    """Late, asleep or compressed links have no compiled twin for learners: the run takes the NumPy backend, says so
    in one note, and gives the NumPy run's numbers."""
    code, out, err = run_cli("learn", "pull-away", "--delay", 2, "-T", 200, "--no-progress", "--no-plots", "--out",
                             tmp_path / "d")  # fmt: skip
    assert code == 0, err
    assert "no compiled twin for learners: they run on the NumPy backend" in err
    code, _, err = run_cli("learn", "pull-away", "--delay", 2, "-T", 200, "--no-progress", "--no-plots",
                           "--backend", "numpy", "--out", tmp_path / "n")  # fmt: skip
    assert code == 0 and "no compiled twin" not in err
    assert (tmp_path / "d" / "metrics.csv").read_bytes() == (tmp_path / "n" / "metrics.csv").read_bytes()


def reducible_team(P) -> team.TeamMDP:
    """One agent with one action on the chain ``P`` (3 states), rewarded 1 in state 1 alone, from a uniform start."""
    P = np.asarray(P, dtype=np.float64)[:, None, :]
    return team.team_mdp(P, np.array([[[0.0], [1.0], [0.0]]]), np.eye(3), 0.5, [1])


def test_the_long_run_average_of_a_multichain_team_mdp_is_the_one_from_its_start():
    """State 0 leaves for the absorbing states 1 (w.p. 1/4) and 2: from the uniform start the chain ends in state 1
    w.p. 1/3 + 1/3 * 1/4 = 5/12, so J = 5/12 (the least-norm stationary solution said 1/2, a mixture no start gives);
    the long-run state distribution is (0, 5/12, 7/12)."""
    mdp = reducible_team([[0, 0.25, 0.75], [0, 1, 0], [0, 0, 1]])
    policies = [np.ones((3, 1))]
    assert team.average_return(mdp, policies) == pytest.approx(5 / 12, abs=1e-15)
    assert_allclose(team.long_run(mdp.chain(policies)[0], mdp.start), [0, 5 / 12, 7 / 12], atol=1e-15)


def test_a_transient_state_leaves_the_critic_target_its_recurrent_values(run_cli, tmp_path):
    """State 0 is left at once for the class {1, 2}: d(0) = 0, so the on-policy fixed point says nothing of state 0's
    weight (tabular features), and on the recurrent class it is the discounted value there, (I - gamma P_CC)^-1 r_C
    (it raised LinAlgError: singular matrix); `dgtd learn` on such a file runs."""
    P = [[0, 0.5, 0.5], [0, 0.3, 0.7], [0, 0.6, 0.4]]
    mdp = reducible_team(P)
    policies = [np.ones((3, 1))]
    target = team.critic_target(mdp, policies)
    C = np.array(P)[1:, 1:]
    assert_allclose(target[1:], np.linalg.solve(np.eye(2) - 0.5 * C, [1.0, 0.0]), atol=1e-14)
    assert team.average_return(mdp, policies) == pytest.approx(6 / 13, abs=1e-15)  # d_C = (6/13, 7/13)
    arrays = dict(P=mdp.P, R=mdp.R, Phi=mdp.Phi, gamma=0.5, policy_0=np.ones((3, 1)))
    np.savez(tmp_path / "t.npz", **arrays)
    code, _, err = run_cli(
        "learn", "--problem", tmp_path / "t.npz", "-T", 200, "--checkpoints", 2, "--seeds", 1, "--no-progress",
        "--no-plots", "--out", tmp_path / "o",
    )  # fmt: skip
    assert code == 0, err
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["return_last"] == pytest.approx([6 / 13], abs=1e-12)
    assert np.isfinite(summary["critic_error_last"]).all()


def test_the_python_api_takes_a_bare_graph_as_its_fixed_network():
    """`dgtd.learn(..., dgtd.ring(4), ...)` and `dgtd.evaluate(..., dgtd.ring(5), ...)` raised AttributeError: a bare
    graph is its network with every link up, the same numbers as `random_edges(graph, 1.0)`; anything else one line."""
    import dgtd

    settings = dgtd.LearnSettings(iterations=50, seeds=1, checkpoints=2, backend="numpy")
    args = (team.pull_away(), make_algorithm("dgtd", alpha0=1.0, beta=100.0), SoftmaxActor(), settings)
    bare = dgtd.learn(args[0], dgtd.ring(4), *args[1:])
    assert np.array_equal(bare.policies, dgtd.learn(args[0], random_edges(dgtd.ring(4), 1.0), *args[1:]).policies)
    sc = dgtd.scenario("paper-example-1")
    result = dgtd.evaluate(sc.problem, dgtd.ring(5), dgtd.DGTD(alpha0=1.0), iterations=20, backend="numpy")
    assert result.w_last.shape == (1, 5, 2)
    with pytest.raises(DgtdInputError, match="a network is dgtd.random_edges"):
        dgtd.evaluate(sc.problem, [(0, 1)], dgtd.DGTD(), iterations=20, backend="numpy")


def test_compare_refuses_to_tune_learners_and_learns_help_gives_its_own_defaults(run_cli, tmp_path):
    """`dgtd compare pull-away --tune` tuned nothing and said nothing; `dgtd learn --help` described --problem in the
    evaluation form and the critics' steps as DGTD's 10 and 1000 (learners take 1 and 100)."""
    code, out, err = run_cli("compare", "pull-away", "--tune", "-T", 10, "--no-progress", "--out", tmp_path / "c")
    one_line_error(code, out, err, "--tune", "learners are compared at the critics' steps given")
    code, out, _ = run_cli("learn", "--help")
    text = " ".join(out.split())
    assert code == 0 and "one starting policy policy_i (S, A_i) per agent" in text
    assert "(default 1 on a task or problem file, 0.1 in a simulator)" in text and "DGTD's 1000" not in text


def test_dgtd_learn_resume_dir_continues_from_its_config_toml(run_cli, tmp_path, monkeypatch):
    """A learning run writes config.toml (the options it was given, --checkpoint-every among them); cut after its
    first checkpoint, `dgtd learn --resume DIR` alone (no task, no options) continues it to the uninterrupted run's
    numbers byte for byte; a finished one is said finished, and a folder with no run, --resume with --overwrite, and
    an option that changes the run are one line each."""
    import tomllib

    import dgtd.cli.learn as cli_learn

    command = ("learn", "pull-away", "-T", 900, "--loss", "0.2", "--seed", 4, "--no-progress", "--no-plots")
    code, _, err = run_cli(*command, "--out", tmp_path / "whole")
    assert code == 0, err
    saved = tomllib.loads((tmp_path / "whole" / "config.toml").read_text())["learn"]
    assert saved["task"] == "pull-away" and saved["iterations"] == 900 and saved["loss"] == "0.2" and saved["seed"] == 4
    keep = cli_learn._keep

    def cut(out, snap, record):
        keep(out, snap, record)
        raise KeyboardInterrupt

    monkeypatch.setattr(cli_learn, "_keep", cut)
    code, _, _ = run_cli(*command, "--checkpoint-every", 300, "--out", tmp_path / "cut")
    assert code != 0 and (tmp_path / "cut" / "learning-checkpoint.npz").exists()
    monkeypatch.setattr(cli_learn, "_keep", keep)
    other = run_cli("learn", "--resume", tmp_path / "cut", "--seed", 5, "--no-progress")
    one_line_error(*other, "checkpoint of another learning run (seed = 4 there, 5 here)")
    code, text, err = run_cli("learn", "--resume", tmp_path / "cut", "--no-progress", "--no-plots")
    assert code == 0 and "resuming" in text and "step 300" in text, err
    assert (tmp_path / "cut" / "metrics.csv").read_bytes() == (tmp_path / "whole" / "metrics.csv").read_bytes()
    code, text, _ = run_cli("learn", "--resume", tmp_path / "cut", "--no-progress")
    assert code == 0 and "already finished" in text
    one_line_error(*run_cli("learn", "--resume", tmp_path / "none"), "is not a directory")
    one_line_error(*run_cli("learn", "--resume", tmp_path / "cut", "--overwrite"), "give one, not both")


def test_a_learning_run_saves_by_time_at_round_ends_and_resumes_from_any():
    """Without a step count, `Saves` saves at the first round's end once the seconds have passed (a clock that ticks
    4 s a call, read at each round's end of 2 steps: 4, 8, 12 s at steps 2, 4, 6; 10 s between saves: steps 6, 12,
    18); a run saving at every round's end (3 steps) resumes from the save at step 21 to the uninterrupted numbers bit
    for bit."""
    from dgtd.run.learn import Saves

    ticks = iter(range(0, 10_000, 4))
    saves = Saves(0, 10.0, 2, clock=lambda: next(ticks))
    assert [k for k in range(1, 20) if saves.due(k)] == [6, 12, 18]
    assert [k for k in range(1, 20) if Saves(5, 10.0, 1).due(k)] == [5, 10, 15]  # (a step count wins)
    mdp, net = team.pull_away(), random_edges(topologies.ring(4), 0.8)
    settings = LearnSettings(iterations=60, seeds=2, checkpoints=3, batch=3)
    critic = make_algorithm("dgtd", alpha0=1.0, beta=100.0)
    snaps: list = []
    whole = learn(mdp, net, critic, SoftmaxActor(), settings, on_checkpoint=snaps.append, checkpoint_seconds=1e-12)
    assert [int(s["k"]) for s in snaps] == list(range(3, 60, 3))
    resumed = learn(mdp, net, critic, SoftmaxActor(), settings, resume=snaps[6])
    assert np.array_equal(whole.policies, resumed.policies) and np.array_equal(whole.critic, resumed.critic)
