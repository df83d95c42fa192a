"""The learning schemes `dgtd learn --scheme` runs, one entry for the command line and sweeps: Zhang et al.'s
actor-critic a step at a time or in rounds (`dgtd.run.learn.learn`), or Chen et al.'s Algorithm 1
(`dgtd.run.chen.learn_chen`, where the job carries its `ChenSteps`)."""

from __future__ import annotations

from dgtd.run.chen import learn_chen
from dgtd.run.learn import learn


def run_job(job, progress=None, on_measured=None, **saves):
    """The learning run of ``job`` (`dgtd.learning.resolve_learning`'s): ``saves`` the checkpoint arguments of
    `dgtd.run.learn.learn` (Chen et al.'s Algorithm 1 keeps none: its run is refused them before)."""
    if getattr(job, "chen", None) is not None:
        return learn_chen(job.mdp, job.network, job.chen, job.settings, progress, on_measured)
    problem = job.env if job.env is not None else job.mdp
    return learn(
        problem, job.network, job.critic, job.actor, job.settings, job.channel, progress, on_measured=on_measured,
        **saves,
    )  # fmt: skip
