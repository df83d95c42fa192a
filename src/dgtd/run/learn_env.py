"""Agents that learn their policies in a simulator, a PettingZoo ParallelEnv (`dgtd learn mpe-spread`, or a user's
env through `learn_env`), where there is no model to solve.

One learning loop runs models and simulators (`dgtd.run.learn.learn`, on `dgtd.sources.team_env.SimulatorEnv`): each
agent's actor is a softmax linear in features of its own observation (`dgtd.algorithms.actor.LinearSoftmaxActor`,
with the steps of the `SoftmaxActor` given): pi_i(a | o_i) = exp(theta_i[a] . x_i) / sum_b exp(theta_i[b] . x_i),
x_i = (o_i, 1). Everything else is the step on a model: the actions drawn
from the keyed streams (purpose ACTION), the critics on features phi(s) of the env's global state (its own reward, or
the team's for centralised actors; differential under the average objective, discounted by the task's gamma under the
discounted one: `dgtd.run.learn.objective_terms`), the networked agents' consensus estimate of the team's reward on
f(s, a) = (phi(s) e_{a_1}^T, ..., phi(s) e_{a_N}^T) (additive over the agents, as on a model), the same links and
`round_end`. A time limit is not terminal: the TD target bootstraps from the state reached.

Without a model the return is estimated: at each checkpoint, the team's mean reward per step over the interval since
the last one (each seed's; `LearnResult.metrics["return"]`), the team's mean return an episode over the episodes that
ended in it (``"episode_return"``: the sum of the team's mean reward over an episode, what shows learning in an
episodic task), and the mean entropy of the policies at the observations met. A simulator's state cannot be saved,
so these runs take no checkpoints to resume from.
"""

from __future__ import annotations

import numpy as np

from dgtd.algorithms.actor import SoftmaxActor
from dgtd.run.learn import LearnResult, LearnSettings, learn
from dgtd.sources.team_env import EnvTask, discrete_actions

__all__ = ["EnvTask", "discrete_actions", "env_summary", "learn_env"]


def learn_env(
    task: EnvTask, network, critic, actor: SoftmaxActor, settings: LearnSettings, channel=None, progress=None,
    on_measured=None,
) -> LearnResult:  # fmt: skip
    """Learners in ``task``'s simulator (the module's docstring); the arguments as `dgtd.run.learn.learn`'s (no
    checkpoints to resume from, the NumPy backend: the simulator's step is the cost)."""
    return learn(task, network, critic, actor, settings, channel, progress, on_measured=on_measured)


def env_summary(result: LearnResult, task: EnvTask, record: dict) -> dict:
    """summary.json of learners in a simulator: what was asked and, per seed, the team's mean reward a step over the
    last interval (``return_last``, estimated: ``return_estimated``); no J* and no policy tables (no model)."""
    return {
        "task": task.name,
        "n_agents": task.n_agents,
        "agents": result.info["agents"],
        "gamma": task.gamma,
        "objective": result.info["objective"],
        "config": record,
        "return_estimated": True,
        "return_first": result.metrics["return"][:, 0].tolist(),
        "return_last": result.metrics["return"][:, -1].tolist(),
        "episode_return_first": _listed(result.metrics["episode_return"][:, 0]),
        "episode_return_last": _listed(result.metrics["episode_return"][:, -1]),
        "return_best": None,
        "entropy_last": result.metrics["entropy"][:, -1].tolist(),
        "messages": result.messages.tolist(),
        "bits": result.bits.tolist(),
        "seconds": result.seconds,
    }


def _listed(x: np.ndarray) -> list:
    """Numbers as JSON holds them: NaN (no episode ended in the interval) as null."""
    return [None if not np.isfinite(v) else float(v) for v in x]
