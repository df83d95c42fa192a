"""The paper-example-2 scenario through the command line and the config layer."""

import json

import numpy as np
import pytest

from dgtd.cli import main
from dgtd.config import FLAT, make_source, resolve, unflat
from dgtd.scenarios.robots import PatrolSource


@pytest.mark.slow  # the whole scenario end to end with its figures and GIF: about 30 s
def test_run_paper_example_2_writes_maps_pictures_and_summary(tmp_path, capsys):
    out = tmp_path / "pe2"
    main(
        [
            "run",
            "paper-example-2",
            "-T",
            "3000",
            "--seeds",
            "2",
            "--checkpoints",
            "30",
            "--no-progress",
            "--out",
            str(out),
        ]
    )
    text = capsys.readouterr().out
    assert "correlation of each agent's map with the reference" in text
    for name in (
        "maps.png",
        "reference.png",
        "snapshots.png",
        "patrol.gif",
        "curves.png",
        "errors.png",
        "summary.json",
        "metrics.csv",
        "trajectory.npz",
    ):
        assert (out / name).stat().st_size > 0, name
    summary = json.loads((out / "summary.json").read_text())
    assert np.asarray(summary["w_last"]).shape == (2, 3, 400)
    assert np.asarray(summary["w_star"]).shape == (400,)
    sc = summary["scenario"]
    assert np.asarray(sc["correlation_last"]).shape == (2, 3)
    assert sc["links_during_run"]["steps"] == 3000 * 2
    assert 0 < sc["links_during_run"]["connected_fraction"] < 1
    assert sc["reference"]["transitions"] >= 10_000_000
    # the recorded config reproduces the run's settings (the scenario's own values are accepted back)
    cfg = {k: v for k, v in summary["config"].items() if k in FLAT}
    assert resolve(unflat(dict(**cfg))).settings.iterations == 3000
    # `dgtd plot` draws every figure the run drew again, from the saved files alone (the robots' paths and links
    # at the recorded steps are saved beside the numbers, in scenario.npz)
    figures = ("maps.png", "reference.png", "snapshots.png", "patrol.gif", "curves.png", "errors.png", "iterates.png")
    drawn = {name: (out / name).read_bytes() for name in figures}
    for name in figures:
        (out / name).unlink()
    main(["plot", str(out)])
    listed = capsys.readouterr().out
    for name in figures:
        assert (out / name).stat().st_size > 0 and name in listed, name
    assert (out / "maps.png").read_bytes() == drawn["maps.png"]  # the same numbers, the same picture


@pytest.mark.parametrize(
    "flags, word",
    [
        (["--graph", "ring"], "--graph"),
        (["--edge-prob", "0.5"], "--edge-prob"),
        (["--sampling", "iid"], "--sampling"),
        (["--reward-noise", "bernoulli"], "--reward-noise"),
    ],
)
def test_flags_that_cannot_apply_to_a_simulated_world_are_refused(flags, word, capsys, tmp_path):
    with pytest.raises(SystemExit) as e:
        main(["run", "paper-example-2", "-T", "10", "--out", str(tmp_path / "x"), *flags])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and word in err and "Traceback" not in err
    assert not (tmp_path / "x").exists()


def test_make_source_gives_every_run_the_same_fresh_robots():
    spec = unflat(dict(scenario="paper-example-2", seeds=2))
    _, _, _, _, settings, resolved, _ = resolve(spec)
    a, b = make_source(resolved, settings), make_source(resolved, settings)
    assert isinstance(a, PatrolSource) and a is not b
    a.start()
    b.start()
    assert np.array_equal(a.next_block(50).up, b.next_block(50).up)
    assert make_source(resolve(unflat(dict(scenario="paper-example-1"))).config, settings) is None


def test_solve_paper_example_2(capsys):
    main(["solve", "paper-example-2"])
    out = json.loads(capsys.readouterr().out)
    assert len(out["w_star"]) == 400 and out["n_agents"] == 3
    assert max(abs(v) for v in out["kkt_residuals"].values()) < 1e-8
