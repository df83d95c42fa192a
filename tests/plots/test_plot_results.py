"""`dgtd plot DIR`: figures from saved results alone, for a run and for a sweep."""

from __future__ import annotations

import numpy as np

from dgtd.config import flat, resolve, unflat
from dgtd.experiments import parse
from dgtd.plots.results import load_run
from dgtd.run.loop import run
from dgtd.run.results import write_results
from dgtd.sweep import run_sweep


def _png(path) -> bool:
    return path.exists() and path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_run_directory_reads_back_exactly(tmp_path, run_cli):
    problem, network, algorithm, samp, settings, resolved, channel = resolve(
        unflat(dict(scenario="paper-example-1", iterations=2000, seeds=3, checkpoints=12, backend="numpy"))
    )
    result = run(problem, network, algorithm, samp, settings)
    write_results(tmp_path, result, flat(resolved), resolved.algorithm.name)
    saved = load_run(tmp_path)
    np.testing.assert_array_equal(saved.steps, result.steps)
    for name, values in result.metrics.items():
        np.testing.assert_array_equal(saved.metrics[name], values)  # CSV keeps every float's digits
    np.testing.assert_array_equal(saved.w_trace, result.w_trace)
    code, out, err = run_cli("plot", tmp_path)
    assert code == 0, err
    assert _png(tmp_path / "errors.png") and _png(tmp_path / "iterates.png")


def test_a_sweep_directory_gives_curves_and_final_errors(tmp_path, run_cli):
    exp = parse(
        {
            "scenario": "paper-example-1",
            "iterations": 1500,
            "seeds": 2,
            "checkpoints": 8,
            "backend": "numpy",
            "grid": {"alpha0": [1.0, 5.0], "kappa": [0.0, 1.0, 2.0]},
            "sweep": {"workers": 2},
        }
    )
    run_sweep(exp, tmp_path / "two", echo=lambda s: None, progress=False)
    code, out, err = run_cli("plot", tmp_path / "two")
    assert code == 0, err
    for name in ("curves.png", "final_error_avg.png", "final_error_last.png"):
        assert _png(tmp_path / "two" / name), name
    assert "final_error_avg.png" in out


def test_plot_refuses_a_directory_without_results(tmp_path, run_cli):
    code, _, err = run_cli("plot", tmp_path)
    assert code == 2 and "not a results directory" in err


def _drawn(monkeypatch, draw):
    """The figure that ``draw()`` would save, kept open to be read."""
    import dgtd.plots
    import dgtd.plots.results

    figures = []
    for module in (dgtd.plots, dgtd.plots.results):  # each holds its own name for it
        monkeypatch.setattr(module, "_save", lambda fig, path: figures.append(fig))
    draw()
    return figures[0]


def _result(steps, w_star, w_trace=None, consensus=None):
    from types import SimpleNamespace

    C = len(steps)
    ones = np.ones((C, 2))
    metrics = {
        "error_last": ones,
        "error_avg": ones,
        "consensus": ones if consensus is None else consensus,
        "mspbe_last": ones,
        "mspbe_avg": ones,
    }
    return SimpleNamespace(steps=np.asarray(steps), w_star=np.asarray(w_star, float), w_trace=w_trace, metrics=metrics)


def test_iterates_of_many_components_show_those_with_the_largest_values(monkeypatch):
    """Of 400 tabular components, the first ones are corner cells with w* near 0: the figure draws the components
    with the largest |w*| and names them."""
    from dgtd.plots import plot_iterates

    w_star = np.zeros(400)
    w_star[[10, 304, 305, 399]] = [5.0, 64.5, 63.9, -70.0]
    trace = np.broadcast_to(w_star, (3, 1, 2, 400)).copy()
    fig = _drawn(monkeypatch, lambda: plot_iterates(_result([1, 2, 3], w_star, trace), "unused"))
    labels = fig.axes[0].get_legend_handles_labels()[1]
    assert [lab.split(" =")[0] for lab in labels if lab.startswith("w*")] == ["w*[11]", "w*[305]", "w*[306]", "w*[400]"]
    assert "largest |w*|" in fig.axes[0].get_title()


def test_an_exact_zero_consensus_is_left_out_of_its_log_axis_and_said(monkeypatch):
    """Before any link is up the agents agree exactly: zero has no place on a log axis, so those checkpoints are not
    drawn (they were drawn at an invented floor) and the legend says until when it was zero."""
    from dgtd.plots import plot_errors

    consensus = np.array([[0.0, 0.0], [0.0, 0.0], [3.0, 5.0], [1.0, 2.0]])
    fig = _drawn(monkeypatch, lambda: plot_errors(_result([1, 10, 100, 1000], [1.0], consensus=consensus), "unused"))
    line = fig.axes[1].get_lines()[0]
    y = np.asarray(line.get_ydata(), float)
    assert np.isnan(y[:2]).all() and np.allclose(y[2:], [4.0, 1.5])
    assert "zero at 2 checkpoints up to k = 10" in line.get_label()


def test_one_seeds_figure_says_one_seed_not_a_median(monkeypatch):
    """One seed has no median and no band: the title says what it is ("one seed"), and two seeds' says median and
    band."""
    from dgtd.plots import plot_errors

    one = _result([1, 10], [1.0])
    one.metrics = {name: x[:, :1] for name, x in one.metrics.items()}
    title = _drawn(monkeypatch, lambda: plot_errors(one, "unused"))._suptitle.get_text()
    assert title.startswith("one seed") and "median" not in title
    two = _drawn(monkeypatch, lambda: plot_errors(_result([1, 10], [1.0]), "unused"))._suptitle.get_text()
    assert two.startswith("median over 2 seeds")


def test_errors_figure_shows_the_tail_average(monkeypatch):
    """The output the README tells users to read, the tail average, is drawn beside the last and averaged iterates,
    for weights and values alike."""
    from dgtd.plots import plot_errors

    result = _result([1, 10, 100], [1.0])
    for name in ("error_tail", "value_error_last", "value_error_avg", "value_error_tail"):
        result.metrics[name] = np.full((3, 2), 0.5)
    result.metrics["error_tail"][0] = np.nan  # before the tail starts
    fig = _drawn(monkeypatch, lambda: plot_errors(result, "unused"))
    labels = fig.axes[0].get_legend_handles_labels()[1]
    assert "tail average, weights" in labels and "tail average, values" in labels


def test_a_sweep_of_many_jobs_draws_small_multiples(monkeypatch):
    """48 jobs (4 x 3 x 4 grid): one panel per value of the first swept parameter, in each one line per setting of the
    others (12, the same colours in every panel), not 48 lines tangled in one panel."""
    from dgtd.plots.results import plot_sweep_curves

    steps = np.array([1, 10, 100])
    points, jobs = {}, {}
    for a in (0.1, 0.3, 1.0, 3.0):
        for kappa in (0.0, 1.0, 3.0):
            for beta in (10.0, 100.0, 1000.0, 10000.0):
                job = f"a{a}-k{kappa}-b{beta}"
                points[job] = {"alpha0": a, "kappa": kappa, "beta": beta}
                jobs[job] = (steps, {name: np.full((3, 2), 0.5) for name in ("error_avg", "consensus", "mspbe_avg")})
    fig = _drawn(monkeypatch, lambda: plot_sweep_curves(jobs, points, "unused"))
    panels = [ax for ax in fig.axes if ax.get_lines()]
    assert len(panels) == 4
    assert [ax.get_title() for ax in panels] == [f"alpha0 = {a:g}" for a in (0.1, 0.3, 1.0, 3.0)]
    assert all(len(ax.get_lines()) == 12 for ax in panels)
    assert len({tuple(np.ravel(line.get_color())) for line in panels[0].get_lines()}) == 12
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert len(labels) == 12 and "kappa=0, beta=10" in labels
