"""Qu, Wierman and Li's scalable actor-critic on networked MDPs (`dgtd.run.scalable`)."""

from __future__ import annotations

import numpy as np
import pytest

from dgtd.errors import DgtdInputError
from dgtd.graphs import topologies
from dgtd.problems.networked import random_networked
from dgtd.run.scalable import Critics, ScalableSteps, exact_return, kappa_hoods, learn_scalable


def test_kappa_hop_neighbourhoods_of_a_path():
    mdp = random_networked(topologies.path(5).edges, 5)
    assert kappa_hoods(mdp, 0).tolist() == [[0], [1], [2], [3], [4]]
    assert kappa_hoods(mdp, 1).tolist() == [[0, 1, -1], [1, 0, 2], [2, 1, 3], [3, 2, 4], [4, 3, -1]]
    assert kappa_hoods(mdp, 2)[2].tolist() == [2, 0, 1, 3, 4]


def test_a_neighbourhoods_state_action_index_puts_its_first_member_first():
    """Agent 1 of a path of 3, kappa 1, members (1, 0, 2): index (s1 A + a1) (SA)^2 + (s0 A + a0) SA + (s2 A + a2)."""
    mdp = random_networked(topologies.path(3).edges, 3, n_states=3, n_actions=2)
    hoods = kappa_hoods(mdp, 1)
    s, a = np.array([[2, 1, 0]]), np.array([[1, 0, 1]])
    critics = Critics(mdp, hoods, seeds=1)
    assert critics.dense
    z = critics.rows(s[None], a[None])[0] - np.arange(3) * 6**3  # (each agent's rows after the agents' before it)
    assert z[0, 1] == (1 * 2 + 0) * 36 + (2 * 2 + 1) * 6 + (0 * 2 + 1)
    assert z[0, 0] == (2 * 2 + 1) * 6 + (1 * 2 + 0)  # agent 0: (0, 1), padded


def test_learners_raise_the_exact_discounted_return_of_their_local_policies():
    """A path of 4 agents, 2 states and actions, gamma 0.7, kappa 1, horizon 10, 600 episodes, 2 seeds: the exact
    J_gamma of the learnt local policies (joint table) rises from the uniform policies' 0.4070 by more than 0.03 in
    every seed (measured 0.465 and 0.464), below J* of global-state policies (0.4999)."""
    mdp = random_networked(topologies.path(4).edges, 4, n_states=2, n_actions=2, gamma=0.7, seed=0)
    uniform = exact_return(mdp, np.full((4, 8, 2), 0.5))
    assert uniform == pytest.approx(0.40695, abs=1e-4)
    result = learn_scalable(mdp, ScalableSteps(kappa=1, horizon=10), 600, seeds=2, checkpoints=3)
    J = result["return"][-1]
    assert (J > uniform + 0.03).all() and (J < 0.5).all(), J


def test_a_seeds_numbers_are_its_own():
    mdp = random_networked(topologies.ring(5).edges, 5, gamma=0.7, seed=1)
    one, two = (learn_scalable(mdp, ScalableSteps(), 30, seeds=b, checkpoints=1) for b in (1, 2))
    assert np.array_equal(one["policies"][0], two["policies"][0])
    assert one["episode_return"][0, 0] == two["episode_return"][0, 0]


@pytest.mark.slow
def test_ten_thousand_agents_learn():
    """A ring of 10 000 agents, kappa 1 (a critic of 64 numbers an agent), 200 episodes of 11 steps, 2 seeds (about
    40 s): the episodes' mean discounted team return rises from 0.514 over the first 50 by more than 0.03 over the
    last 50 (measured 0.555), every seed."""
    mdp = random_networked(topologies.ring(10_000).edges, 10_000, gamma=0.7, seed=0)
    result = learn_scalable(mdp, ScalableSteps(kappa=1, horizon=10), 200, seeds=2, checkpoints=4)
    first, last = result["episode_return"][0], result["episode_return"][-1]
    assert np.isnan(result["return"]).all()  # (no joint table at this size: estimated only)
    assert (last > first + 0.03).all(), (first, last)


@pytest.mark.parametrize("restart", [0, 7])
def test_hashed_critics_give_the_dense_tables_numbers(monkeypatch, restart):
    """A critic's table indexed by its configurations' fingerprints (`FingerprintTable`, where (S A)^K is too large
    for a dense one) gives the dense table's numbers bit for bit, with tables from 0 each episode or kept over them."""
    from dgtd.run import scalable

    mdp = random_networked(topologies.path(4).edges, 4, gamma=0.7, seed=0)
    steps = ScalableSteps(kappa=1, horizon=6, restart=restart, critic_power=0.5)
    dense = learn_scalable(mdp, steps, 60, seeds=2, checkpoints=2)
    monkeypatch.setattr(scalable, "DENSE_MAX", 0)
    hashed = learn_scalable(mdp, steps, 60, seeds=2, checkpoints=2)
    assert np.array_equal(dense["policies"], hashed["policies"])
    assert np.array_equal(dense["episode_return"], hashed["episode_return"])


def test_the_steps_of_the_papers_form_and_of_their_codes():
    paper = ScalableSteps(critic_step=2.0, critic_offset=3.0, actor_step=0.5)
    assert paper.critic_rate(40, 1) == 2.0 / 3.0 and paper.critic_rate(40, 4) == 2.0 / 6.0  # (from 0 each episode)
    assert paper.actor_rate(3) == 0.25
    code = ScalableSteps(horizon=10, critic_power=0.5, actor_step=5.0, restart=100)  # 1/sqrt((m % 100) T + t)
    assert code.critic_rate(205, 3) == pytest.approx(1 / np.sqrt(5 * 10 + 3)) and code.critic_rate(300, 1) == 1.0
    assert code.actor_rate(199) == pytest.approx(5.0 / 10.0)


@pytest.mark.slow
def test_the_wireless_benchmark_learns_as_published():
    """The published wireless-access setting (24 users, kappa 1, their code's steps), 20 000 episodes of the 120 000
    (about 60 s): the return of 400 keyed rollouts rises from the uniform policies' 0.020 to above 0.035 (measured
    0.045; their published curve 0.049 at 20 000); the full run is benchmarks/wireless.py."""
    from dgtd.problems.wireless import published

    task = published()
    steps = ScalableSteps(kappa=1, horizon=10, critic_power=0.5, actor_step=5.0 / 24, restart=100)
    result = learn_scalable(task, steps, 20_000, seeds=1, checkpoints=2, evaluate=400)
    assert result["evaluated"][-1, 0] > 0.035, result["evaluated"]


def test_forgetting_critics_hold_at_most_a_restarts_configurations(monkeypatch):
    """With ``forget`` each critic's table starts from 0 at each restart: after 25 episodes of restarts every 10, the
    hashed table holds at most the last 5 episodes' configurations; within the first restart, the numbers of tables
    kept."""
    from dgtd.problems.wireless import grid
    from dgtd.run import scalable

    task, tables = grid(2, 2, 2), []
    original = scalable.Critics.clear

    def clear(self):
        original(self)
        tables.append(self)

    monkeypatch.setattr(scalable.Critics, "clear", clear)
    steps = ScalableSteps(kappa=1, horizon=4, critic_power=0.5, restart=10, forget=True)
    learn_scalable(task, steps, 25, seeds=1, checkpoints=1)
    critics = tables[-1]
    assert len(tables) == 1 + 3 and not critics.dense  # (made, then cleared at episodes 0, 10 and 20)
    assert 0 < critics.table.count <= 5 * 5 * task.n_agents
    kept = learn_scalable(task, ScalableSteps(kappa=1, horizon=4, critic_power=0.5, restart=10), 10, seeds=1)
    forgot = learn_scalable(task, steps, 10, seeds=1)
    assert np.array_equal(kept["policies"], forgot["policies"])


def test_lost_messages_are_keyed_and_cost_what_they_lose():
    """Messages lost with probability p: each agent's own always heard, a member's state and action (u0) and value
    (u1) by their own keyed numbers (about p of them lost: 2 200 numbers of Bernoulli(0.3), standard error 0.01,
    0.04 allowed); loss 0 gives the lossless numbers bit for bit."""
    from dgtd.run.scalable import heard

    mdp = random_networked(topologies.ring(10).edges, 10, gamma=0.7, seed=0)
    hoods = kappa_hoods(mdp, 1)
    pairs, values = heard(hoods, np.array([11, 12], dtype=np.uint64), 3, 10, 0.3)
    assert pairs.shape == (11, 2, 10, 3) and pairs[..., 0].all() and values[..., 0].all()
    assert (1 - pairs[..., 1:].mean()) == pytest.approx(0.3, abs=0.04) and not np.array_equal(pairs, values)
    assert heard(hoods, np.array([11], dtype=np.uint64), 3, 10, 0.0) == (None, None)
    steps = ScalableSteps(kappa=1, horizon=6)
    clean, none_lost = (learn_scalable(mdp, steps, 40, seeds=2, checkpoints=1, loss=p) for p in (0.0, 0.0))
    lossy = learn_scalable(mdp, steps, 40, seeds=2, checkpoints=1, loss=0.3)
    assert np.array_equal(clean["policies"], none_lost["policies"])
    assert not np.array_equal(clean["policies"], lossy["policies"])
    with pytest.raises(DgtdInputError, match="loss probability"):
        learn_scalable(mdp, steps, 1, loss=1.0)


@pytest.mark.parametrize("dense", [True, False])
def test_a_run_resumed_from_a_checkpoint_ends_with_the_uninterrupted_numbers(monkeypatch, dense, tmp_path):
    """Through the checkpoint file format, dense and hashed critics, tables kept over episodes."""
    from dgtd.run import scalable
    from dgtd.run.checkpoint import load_checkpoint, save_checkpoint

    if not dense:
        monkeypatch.setattr(scalable, "DENSE_MAX", 0)
    mdp = random_networked(topologies.ring(6).edges, 6, gamma=0.7, seed=2)
    steps = ScalableSteps(kappa=1, horizon=5, critic_power=0.5, restart=7)
    whole = learn_scalable(mdp, steps, 30, seeds=2, checkpoints=3, evaluate=5)
    snaps: list = []
    learn_scalable(mdp, steps, 30, seeds=2, checkpoints=3, evaluate=5, checkpoint_every=13, on_checkpoint=snaps.append)
    assert [s["m"] for s in snaps] == [13, 26]
    save_checkpoint(tmp_path / "c.npz", snaps[0], {"x": 1})
    resumed = learn_scalable(mdp, steps, 30, seeds=2, checkpoints=3, evaluate=5,
                             resume=load_checkpoint(tmp_path / "c.npz")[0])  # fmt: skip
    for name in ("policies", "episode_return", "evaluated", "return"):
        assert np.array_equal(whole[name], resumed[name], equal_nan=True), name
