"""`dgtd plot DIR` on learning results draws the learning figures again from the saved files: a learning run's
returns.png (a diverged one's too: its critics' error all NaN, no log scale to fail), a learners' comparison's
learners.png, and a sweep of learning runs' returns.png, never the evaluation runs' panels or a 'cut off?' refusal."""

from __future__ import annotations


def test_dgtd_plot_draws_a_learning_runs_figures_again(run_cli, tmp_path):
    base = ("--no-plots", "--no-progress")
    code, _, err = run_cli("learn", "pull-away", "-T", 400, "--checkpoints", 2, *base, "--out", tmp_path / "l")
    assert code == 0, err
    code, _, err = run_cli("learn", "pull-away", "--algorithm", "consensus-td0", "--alpha0", 1000, "-T", 1200,
                           "--checkpoints", 4, "--backend", "numpy", *base, "--out", tmp_path / "d")  # fmt: skip
    assert code == 0, err
    code, _, err = run_cli("compare", "pull-away", "-T", 400, *base, "--out", tmp_path / "c")
    assert code == 0, err
    for folder, figure in (("l", "returns.png"), ("d", "returns.png"), ("c", "learners.png")):
        code, text, err = run_cli("plot", tmp_path / folder)
        assert code == 0 and figure in text and (tmp_path / folder / figure).stat().st_size > 10_000, (folder, err)


def test_dgtd_plot_draws_a_learning_sweeps_returns(run_cli, tmp_path):
    (tmp_path / "s.toml").write_text(
        '[learn]\ntask = "pull-away"\niterations = 400\ncheckpoints = 2\n\n'
        '[grid]\nactor = ["networked", "independent"]\n'
    )
    code, _, err = run_cli("sweep", tmp_path / "s.toml", "--out", tmp_path / "s", "--no-progress")
    assert code == 0, err
    code, text, err = run_cli("plot", tmp_path / "s")
    assert code == 0 and "returns.png" in text and not (tmp_path / "s" / "curves.png").exists(), err
