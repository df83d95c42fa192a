"""Tuned step sizes: one table, an entry for every algorithm and task, and what `dgtd compare` runs each at."""

from __future__ import annotations

import pytest

from dgtd.algorithms import ALGORITHMS, make_algorithm
from dgtd.run.compare import configs_for
from dgtd.scenarios import get_scenario
from dgtd.scenarios.tuned import TASKS, TUNED_STEPS


def test_every_algorithm_has_tuned_steps_for_every_task():
    assert set(TUNED_STEPS) == set(ALGORITHMS)
    for name, steps in TUNED_STEPS.items():
        assert set(steps) == set(TASKS), name
        for fields in steps.values():
            make_algorithm(name, **fields)  # every field is one of the algorithm's, with a valid value


@pytest.mark.parametrize("task", [t for t in TASKS if t != "paper-example-2"])  # its reference chain takes seconds
def test_compare_runs_every_algorithm_at_its_tuned_steps(task):
    """On each task, every algorithm's config is its tuned alpha0 under the task's schedule and offset; the task's
    own algorithm keeps its own settings unless the table sets them (DGTD's defaults on the paper's Example 1)."""
    sc = get_scenario(task)
    configs = configs_for(sc, tuple(ALGORITHMS))
    for name, alg in configs.items():
        fields = TUNED_STEPS[name][task]
        for field, value in fields.items():
            assert getattr(alg, field) == value, (task, name, field)
        if name != sc.algorithm.name:
            assert (alg.schedule, alg.beta) == (sc.algorithm.schedule, sc.algorithm.beta)
        elif not fields:
            assert alg == sc.algorithm
