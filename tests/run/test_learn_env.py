"""Learners in a simulator (`dgtd learn mpe-spread`, `dgtd.run.learn` on `dgtd.sources.team_env.SimulatorEnv`): actors
linear in their own observations, dgtd's critics on features of the env's state, the return estimated from the run's
own rewards. A PettingZoo env written here, the pull-away game without a model, checks that the learners learn what
they should; MPE2's simple_spread runs from the command line with its results and its refusals."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers import one_line_error

from dgtd.algorithms import make_algorithm
from dgtd.algorithms.actor import SoftmaxActor
from dgtd.graphs import topologies
from dgtd.graphs.random import random_edges
from dgtd.run.learn import LearnSettings, learn
from dgtd.sources.team_env import EnvTask


class PullAwayGame:
    """A PettingZoo ParallelEnv of N agents and one state, 2 actions: deviating (action 1) pays the deviator 1 and
    costs each other agent 2 / (N - 1), so that the team's mean reward falls by 1 / N a deviator; episodes of 10
    steps. The team's best joint action is nobody deviating; each agent's own reward says deviate."""

    metadata = {"name": "pull_away_game"}

    def __init__(self, n: int = 2):
        from gymnasium.spaces import Box, Discrete

        self.possible_agents = [f"a{i}" for i in range(n)]
        self._actions, self._obs = Discrete(2), Box(0.0, 1.0, (1,))
        self.agents: list = []

    def action_space(self, agent):
        return self._actions

    def observation_space(self, agent):
        return self._obs

    def reset(self, seed=None, options=None):
        self.agents, self.t = list(self.possible_agents), 0
        return {a: np.zeros(1) for a in self.agents}, {a: {} for a in self.agents}

    def step(self, actions):
        n, self.t = len(self.agents), self.t + 1
        out = {a: float(actions[a]) for a in self.agents}
        deviators = sum(out.values())
        rewards = {a: out[a] - 2.0 * (deviators - out[a]) / (n - 1) for a in self.agents}
        done = self.t >= 10
        obs = {a: np.zeros(1) for a in self.agents}
        flags = {a: done for a in self.agents}
        if done:
            self.agents = []
        return obs, rewards, {a: False for a in flags}, flags, {a: {} for a in flags}


def game(actor: str, iterations: int = 3000):
    task = EnvTask(PullAwayGame, lambda states: np.ones((len(states), 1)), 0.5, "pull-away-game", 2)
    settings = LearnSettings(iterations=iterations, seeds=2, checkpoints=3, actor=actor)
    critic = make_algorithm("dgtd", alpha0=1.0, beta=100.0)
    return learn(task, random_edges(topologies.ring(2), 1.0), critic, SoftmaxActor(step=0.5), settings)


def probability_of_cooperating(result) -> np.ndarray:
    """(B, N): each agent's probability of action 0 (its observation is always 0: x = (0, 1))."""
    logits = result.policies[..., -1]  # (B, N, A): the constant feature's weights
    z = np.exp(logits - logits.max(axis=-1, keepdims=True))
    return (z / z.sum(axis=-1, keepdims=True))[..., 0]


@pytest.mark.parametrize("actor, cooperates", [("networked", True), ("independent", False), ("centralised", True)])
def test_learners_in_a_simulator_find_what_their_rewards_say(actor, cooperates):
    """In the pull-away game without a model: networked learners (consensus on the team's reward) and centralised
    ones put at least 0.9 on cooperating within 3 000 steps in every seed and agent; independent ones, each pulled by
    its own reward, put at most 0.1 there. Measured: at least 0.997, and at most 0.0012: wide margins; seeded."""
    p = probability_of_cooperating(game(actor))
    assert (p > 0.9).all() if cooperates else (p < 0.1).all(), p


def test_a_simulators_learners_are_reproducible_and_estimate_the_return():
    """The same seed gives the same numbers (the actions drawn from the keyed streams, the episodes seeded by key);
    the return is the team's mean reward a step over each checkpoint's interval: 0 at best, -1/2 a deviator."""
    one, two = game("networked", 600), game("networked", 600)
    assert np.array_equal(one.policies, two.policies)
    for name in one.metrics:
        assert np.array_equal(one.metrics[name], two.metrics[name], equal_nan=True)
    assert ((one.metrics["return"] <= 0) & (one.metrics["return"] >= -1)).all()
    assert one.info["estimated"]


def test_dgtd_learn_mpe_spread_writes_its_estimated_returns(run_cli, tmp_path):
    code, out, err = run_cli(
        "learn", "mpe-spread", "-T", 200, "--checkpoints", 2, "--no-progress", "--out", tmp_path / "s"
    )
    assert code == 0, err
    summary = json.loads((tmp_path / "s" / "summary.json").read_text())
    assert summary["return_estimated"] and summary["return_best"] is None and len(summary["return_last"]) == 2
    theta = np.load(tmp_path / "s" / "actors.npz")["theta"]
    assert theta.shape == (2, 3, 5, 19)  # seeds, agents, MPE's 5 moves, an observation of 18 and a constant
    rows = (tmp_path / "s" / "metrics.csv").read_text().splitlines()
    assert rows[0] == "actor,seed,step,metric,value" and len(rows) == 1 + 2 * 2 * 7  # 6 metrics, episode_return
    assert (tmp_path / "s" / "returns.png").exists()


@pytest.mark.parametrize(
    "args, words",
    [
        (["--ranks", "2"], ["simulator", "--ranks"]),
        (["--checkpoint-every", "100"], ["simulator", "--checkpoint-every"]),
        (["--values", "action"], ["simulator", "--values action"]),
        (["--agents", "1"], ["at least 2 agents"]),
    ],
)
def test_what_a_simulator_cannot_do_is_one_line(run_cli, tmp_path, args, words):
    one_line_error(*run_cli("learn", "mpe-spread", *args, "-T", 10, "--no-progress", "--out", tmp_path / "o"), *words)


def test_dgtd_compare_learns_in_a_simulator_too(run_cli, tmp_path):
    """`dgtd compare mpe-spread --learn`: the learners side by side on the same keyed numbers, the table saying that
    its returns are estimated."""
    code, out, err = run_cli(
        "compare", "mpe-spread", "--learn", "-a", "dgtd", "-T", 100, "--checkpoints", 2, "--seeds", 1,
        "--no-progress", "--out", tmp_path / "c",
    )  # fmt: skip
    assert code == 0, err
    summary = json.loads((tmp_path / "c" / "summary.json").read_text())
    assert {"networked/dgtd", "independent/dgtd", "centralised/dgtd"} <= set(summary)
    assert "estimated from the run's own rewards" in out
    # (a simulator has no critic error to measure: not a failed seed, and the highest return is named)
    assert "highest return:" in out and "every learners had a failed seed" not in out
    row = next(line for line in out.splitlines() if line.startswith("networked/dgtd")).split()
    assert row[3] == "to", row  # (J and the seeds' range ran together: "-0.8214-0.8214 to -0.8214")
    assert all(summary[label]["failed_seeds"] == 0 for label in ("networked/dgtd", "independent/dgtd"))


def test_dgtd_learn_env_learns_in_a_users_simulator(run_cli, tmp_path):
    """`dgtd learn --env file.py:make --features linear`: a user's ParallelEnv (the pull-away game, written to a file
    as a user would), its critics' features built as `dgtd run --env`'s; networked learners end cooperating (the
    team's mean reward a step, estimated, above -0.05 at the end in both seeds, from about -0.5 a deviator)."""
    user_game(tmp_path)
    code, out, err = run_cli(
        "learn", "--env", f"{tmp_path / 'game.py'}:make", "--features", "linear", "-T", 3000, "--actor-step", 0.5,
        "--alpha0", 1, "--beta", 100, "--checkpoints", 3, "--no-progress", "--no-plots", "--out", tmp_path / "u",
    )  # fmt: skip
    assert code == 0, err
    summary = json.loads((tmp_path / "u" / "summary.json").read_text())
    assert summary["n_agents"] == 2 and min(summary["return_last"]) > -0.05, summary["return_last"]
    one_line_error(
        *run_cli("learn", "mpe-spread", "--env", f"{tmp_path / 'game.py'}:make", "--out", tmp_path / "x"), "name one"
    )


@pytest.mark.parametrize("gamma", ["1.5", "-0.5", "nan", "inf"])
def test_a_simulators_discount_outside_0_1_is_one_line(run_cli, tmp_path, gamma):
    """`dgtd learn --env ... --gamma` is checked as `dgtd run --env`'s is (these ran with exit 0, NaN actors too)."""
    user_game(tmp_path)
    args = ("learn", "--env", f"{tmp_path / 'game.py'}:make", "--features", "linear", "--gamma", gamma, "-T", 10)
    one_line_error(*run_cli(*args, "--no-progress", "--out", tmp_path / "o"), "gamma must be in [0, 1]")


def test_a_named_simulator_runs_at_the_discount_given(run_cli, tmp_path):
    """`dgtd learn mpe-spread --objective discounted --gamma 0.7`: the critics' discount is 0.7 (it was 0.9 whatever
    was given)."""
    code, _, err = run_cli(
        "learn", "mpe-spread", "--objective", "discounted", "--gamma", 0.7, "-T", 20, "--checkpoints", 1, "--seeds",
        1, "--no-progress", "--no-plots", "--out", tmp_path / "g",
    )  # fmt: skip
    assert code == 0, err
    summary = json.loads((tmp_path / "g" / "summary.json").read_text())
    assert summary["gamma"] == 0.7 and summary["objective"] == "discounted"


def user_game(tmp_path) -> None:
    """The pull-away game written to game.py with its ``make`` as a user would write it."""
    import inspect

    source = (
        "import numpy as np\n\n\n" + inspect.getsource(PullAwayGame) + "\n\ndef make():\n    return PullAwayGame()\n"
    )
    (tmp_path / "game.py").write_text(source)


@pytest.mark.parametrize(
    "make, words",
    [
        ("make_box_actions", ["make_box_actions", "same discrete actions", "softmax actor", "Box"]),  # (--policy)
        ("make_no_agents", ["make_no_agents", "has no agents"]),  # (said "a graph needs at least one node")
    ],
)
def test_a_simulator_learners_cannot_act_in_is_one_line(run_cli, tmp_path, make, words):
    from pathlib import Path

    chain = Path(__file__).resolve().parents[1] / "envs" / "chain.py"
    one_line_error(
        *run_cli("learn", "--env", f"{chain}:{make}", "-T", 10, "--no-progress", "--out", tmp_path / "o"), *words
    )


def test_an_episodic_simulator_reports_the_team_return_an_episode(run_cli, tmp_path):
    """The pull-away game's episodes are 10 steps and the checkpoints fall every 1 000 steps (100 episodes): the
    team's mean return an episode equals 10 times its mean reward a step over each interval (to 1e-12), and the
    command says it first -> last (in an episodic task "mean reward a step" could not show learning)."""
    result = game("networked")
    assert np.allclose(result.metrics["episode_return"], 10 * result.metrics["return"], rtol=0, atol=1e-12)
    user_game(tmp_path)
    code, out, err = run_cli("learn", "--env", f"{tmp_path / 'game.py'}:make", "--features", "linear", "-T", 200,
                             "--checkpoints", 2, "--no-progress", "--no-plots", "--out", tmp_path / "o")  # fmt: skip
    assert code == 0, err
    assert "team's mean return an episode" in out
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert len(summary["episode_return_last"]) == 2
