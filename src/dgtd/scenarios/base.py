"""A named scenario: a ready-to-run setting (`Scenario`), which every scenario module returns."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from dgtd.algorithms.dgtd import DGTD
from dgtd.graphs.random import RandomEdges
from dgtd.problems.model import Problem
from dgtd.sources.model import Sampling


@dataclass(frozen=True, eq=False)
class Scenario:
    """A ready-to-run setting; ``iterations`` is the run length the scenario is meant to be judged at."""

    problem: Problem
    network: RandomEdges
    algorithm: DGTD
    sampling: Sampling
    iterations: int
    description: str
    source: Callable[..., object] | None = None
    """Factory ``source(seed, seed_ids)`` of the run's samples, for a simulator whose samples do not come from
    the model (hidden state, links set by positions): anything with start/next_block/get_state/set_state (see
    `dgtd.sources.model.ModelSource`). None: samples are drawn from ``problem`` over ``network``. Every command
    that runs an algorithm on the scenario should pass a fresh one as ``run(..., source=...)``
    (`dgtd.config.make_source`), so that every algorithm sees the same samples and links."""
    report: Callable[..., tuple] | None = None
    """Optional ``report(result, source) -> (dict, text)`` after a run: scenario-specific numbers for summary.json
    (under "scenario") and lines to print; its figures, if any, are drawn by `dgtd.plots.scenario_figures`."""
    data: object | None = None
    """The `dgtd.sources.data.TransitionFile` of a run on recordings (how many there are, and how long)."""
    compare_settings: dict = field(default_factory=dict)
    """Algorithm name -> settings (e.g. {"alpha0": 1.0}) used when `dgtd compare` runs it on this scenario
    (`dgtd.scenarios.tuned.TUNED_STEPS`); for the scenario's own algorithm they override ``algorithm``'s only in
    comparisons (`dgtd.run.compare.configs_for`)."""
    compare_note: str = "tuned on this task (dgtd.scenarios.tuned; docs/benchmarks.md)"
    """Where ``compare_settings`` come from, as `dgtd compare` says it."""
