"""`dgtd compare` on learners says what its numbers are (issue 60): p(best)'s median beside its worst seed, a failed
seed counted and kept out of "highest", ties called ties, a learner that sends nothing drawn."""

from __future__ import annotations

import numpy as np

from dgtd.cli.learn import _learners_table
from dgtd.plots.learning import learners_figure
from dgtd.run.learn import METRICS, LearnResult


def result(J_last, p_best, sent=1.0) -> LearnResult:
    B = len(J_last)
    metrics = {name: np.ones((2, B)) for name in METRICS}  # (checkpoints, seeds)
    metrics["return"][-1], metrics["best_probability"][-1] = J_last, p_best
    metrics["critic_error"][-1] = np.where(np.isfinite(J_last), 1e-3, np.nan)
    metrics["bits"] *= sent
    return LearnResult(np.array([1, 2]), metrics, np.zeros((B, 2, 3, 2)), np.zeros((B, 2, 3)), 2.0, None,
                       np.full(B, sent), np.full(B, sent), 0.1, {"objective": "average"})  # fmt: skip


def test_the_learners_table_shows_medians_worst_seeds_failures_and_ties():
    """A: median J 1.99 over seeds 1.98-2.0, p(best) median 0.99 and worst 0.02; B: a failed (NaN) seed and the
    highest median of the finite ones; C: 1.95-1.981, overlapping A's range; D: far below. The highest is A (B failed),
    C tied with it, D not."""
    table = _learners_table({
        "A": result([1.98, 1.99, 2.0], [0.99, 0.995, 0.02]),
        "B": result([np.nan, 1.999, 1.999], [0.99, 0.99, 0.99]),
        "C": result([1.95, 1.96, 1.981], [0.9, 0.9, 0.9]),
        "D": result([1.0, 1.0, 1.0], [0.0, 0.0, 0.0]),
    })  # fmt: skip
    a = next(line for line in table.splitlines() if line.startswith("A "))
    assert "0.990 (0.020)" in a and "0 of 3" in a
    assert "1 of 3" in next(line for line in table.splitlines() if line.startswith("B "))
    last = table.splitlines()[-1]
    assert last.startswith("highest return: A, 1.99") and "tied with it" in last and "C" in last and "D" not in last


def test_a_learner_that_sends_nothing_is_drawn(tmp_path, monkeypatch):
    """Its point at 0 megabytes carries its label (a line of one x drew nothing)."""
    import matplotlib.pyplot as plt

    seen = []
    plot = plt.Axes.plot

    def spy(self, *args, **kwargs):
        seen.append(kwargs.get("label"))
        return plot(self, *args, **kwargs)

    monkeypatch.setattr(plt.Axes, "plot", spy)
    learners_figure(tmp_path, {"talks": result([1.0], [1.0]), "quiet": result([1.0], [1.0], sent=0.0)}, "t")
    assert "quiet (sends nothing)" in seen and (tmp_path / "learners.png").exists()


def test_a_long_learning_run_says_how_long_early_and_once():
    """`dgtd learn factored --agents 1000` said "about 0.2 s a step" and not the 3 hours its defaults take: the probe
    times steps 5 onwards (past the kernels' compilation) for a second and says the time left once, where it is more
    than a minute; a short run says nothing."""
    from dgtd.cli.learn import CostProbe

    for total, per_step, expected in ((20_000, 0.5, "about 2.8 hours"), (1000, 0.01, None)):
        clock, said = iter(per_step * np.arange(1, total + 1)), []
        probe = CostProbe(total, clock=lambda clock=clock: next(clock), say=said.append)
        for _ in range(total):
            probe(1)
        assert (said == []) if expected is None else (len(said) == 1 and expected in said[0]), said
    clock, said = iter(0.5 * np.arange(1, 20_001)), []
    probe = CostProbe(20_000, clock=lambda: next(clock), say=said.append, saves=300.0)
    for _ in range(20_000):
        probe(1)
    assert "its state is saved every 5 minutes: the same command continues it" in said[0]  # (a learning run's default)
