"""Step sizes tuned per task for every algorithm: what `dgtd compare` runs each at (`dgtd.run.compare.configs_for`),
and where `dgtd compare --tune` and benchmarks/time_to_accuracy.py start their search.

`TUNED_STEPS[algorithm][task]` holds the fields set on the algorithm (its alpha0; DGTD's on paper-example-1 also its
beta and kappa), under the task's step-size schedule and offset beta (its scenario's). Each is the best alpha0 of the
grid 10^(k/2) by `dgtd.run.compare.tune_score` on 2 seeds of streams separate from the reported ones, rounded
(docs/benchmarks.md has the search). DGTD's entry is empty where its scenario's own settings are the tuned ones; on
the paper's Example 1 the scenario keeps the paper's steps for `dgtd run`, while comparisons use DGTD's defaults. On
Baird every algorithm runs at the constant 0.02 of its scenario: the TD methods diverge at every step size, and the
gradient methods settle only along a slow direction. paper-example-2's tabular features have unit scale, as
garnet's, whose steps it takes (not tuned on it). Every algorithm has an entry for every task (tested).
"""

from __future__ import annotations

TASKS = (
    "paper-example-1",
    "paper-example-2",
    "baird",
    "boyan",
    "random-mdp",
    "random-mdp-off",
    "garnet",
    "random-walk",
)


def _alpha0(*values: float) -> dict:
    """{task: {"alpha0": value}} for the tasks in `TASKS`' order, paper-example-2 taking garnet's."""
    tasks = [t for t in TASKS if t != "paper-example-2"]
    out = {task: {"alpha0": float(v)} for task, v in zip(tasks, values, strict=True)}
    return out | {"paper-example-2": out["garnet"]}


TUNED_STEPS: dict[str, dict[str, dict]] = {
    "dgtd": {
        "paper-example-1": {"alpha0": 10.0, "beta": 1000.0, "kappa": 3.0},
        "random-walk": {"alpha0": 30.0},
        **{task: {} for task in TASKS if task not in ("paper-example-1", "random-walk")},
    },
    #                          paper-example-1, baird, boyan, random-mdp, random-mdp-off, garnet, random-walk
    "gtd2": _alpha0(1.0, 0.02, 30.0, 0.3, 0.3, 3.0, 30.0),
    "tdc": _alpha0(1.0, 0.02, 30.0, 0.3, 0.3, 3.0, 30.0),
    "td0": _alpha0(0.3, 0.02, 1.0, 3.0, 3.0, 1.0, 3.0),
    "consensus-td0": _alpha0(0.3, 0.02, 1.0, 1.0, 1.0, 1.0, 3.0),
    "pd-td": _alpha0(0.3, 0.02, 1.0, 1.0, 1.0, 1.0, 3.0),
    "td-tracking": _alpha0(0.3, 0.02, 0.3, 1.0, 1.0, 1.0, 3.0),
    "tdc-tracking": _alpha0(0.3, 0.02, 3.0, 0.1, 0.1, 3.0, 10.0),
    "tdrc": _alpha0(0.3, 0.02, 0.3, 0.3, 0.3, 1.0, 3.0),
    "consensus-tdrc": _alpha0(0.3, 0.02, 0.3, 0.3, 0.3, 1.0, 3.0),
    "local": _alpha0(1.0, 0.02, 10.0, 0.3, 0.1, 3.0, 10.0),
}


def tuned_steps(task: str) -> dict:
    """Algorithm name -> the fields `dgtd compare` sets on it on ``task``."""
    return {name: dict(steps[task]) for name, steps in TUNED_STEPS.items()}
