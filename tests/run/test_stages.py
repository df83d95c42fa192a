"""The run as named stages over one run state: the state's fields declared once, and saving, restoring, putting
shards together and gathering all read that declaration; one channel built per `dgtd run`."""

from __future__ import annotations

from dataclasses import fields

import numpy as np
from numpy.testing import assert_array_equal

from dgtd.config import resolve, unflat
from dgtd.run import state
from dgtd.run.loop import run
from dgtd.run.state import AGENTS, ARCS, RunState, gathered, restore


def declared(kind: str) -> dict:
    return {f.name: f.metadata["axis"] for f in fields(RunState) if f.metadata["rows"] == kind}


def test_the_checkpoints_rows_are_the_declarations():
    assert state.AGENT_AXES == declared(AGENTS)
    assert set(state.ARC_FIELDS) == set(declared(ARCS)) == {"channel", "per_arc"}


def snapshots_of_a_run(resume=None, **options) -> tuple[list, object, object]:
    """The snapshots a garnet run saves every 100 steps (from ``resume`` where given), its result and its config."""
    spec = unflat(dict(scenario="garnet", iterations=300, seeds=2, checkpoints=5, backend="numpy", **options))
    r = resolve(spec)
    saved: list = []
    result = run(
        r.problem,
        r.network,
        r.algorithm,
        r.sampling,
        r.settings,
        checkpoint_every=100,
        on_checkpoint=saved.append,
        channel=r.channel,
        resume=resume,
    )
    return saved, result, r


def test_a_snapshot_holds_every_declared_field_that_holds_something_and_nothing_else():
    saved, _, _ = snapshots_of_a_run(loss=0.2)
    names = {f.name for f in fields(RunState)}
    for snap in saved:
        assert set(snap) <= names, set(snap) - names
        assert {"k", "c", "seconds", "state", "sums", "metrics", "counts", "channel", "source"} <= set(snap)
        assert "message_ages" not in snap  # (asynchronous ranks only)


def test_restore_puts_back_every_declared_field_of_a_snapshot():
    saved, _, _ = snapshots_of_a_run(delay=2, bits=8)
    snap = saved[-1]
    blank = RunState(
        state=type_of_state(snap)(**{f: np.zeros_like(x) for f, x in snap["state"].items()}),
        sums={"all": np.zeros_like(snap["sums"]["all"])},
        metrics={m: np.zeros_like(x) for m, x in snap["metrics"].items()},
        counts={m: np.zeros_like(x) for m, x in snap["counts"].items()},
        messages=np.zeros(2),
        diverged_at=np.zeros(2, np.int64),
    )
    back = restore(blank, snap)
    assert (back.k, back.c) == (snap["k"], snap["c"])
    for name in ("sums", "metrics", "counts"):
        for key, x in snap[name].items():
            assert_array_equal(getattr(back, name)[key], x)
    for f, x in snap["state"].items():
        assert_array_equal(getattr(back.state, f), x)
    assert back.diverged_at.dtype == np.int64  # as the initial state has it


def type_of_state(snap):
    from typing import NamedTuple

    return NamedTuple("State", [(f, np.ndarray) for f in snap["state"]])


class Recording:
    """A layout that records which rows it was asked to gather, and on which axis."""

    def __init__(self):
        self.asked: list = []

    def whole(self, x, axis=1):
        self.asked.append(("agents", axis, np.shape(x)))
        return x

    def whole_arcs(self, x, n_arcs):
        self.asked.append(("arcs", n_arcs, np.shape(x)))
        return x


def test_gathered_takes_exactly_the_declared_fields_on_their_axes():
    saved, _, _ = snapshots_of_a_run()
    snap = saved[-1]
    rs = restore(
        RunState(
            state=type_of_state(snap)(**snap["state"]),
            sums=snap["sums"],
            agent_error_last=snap["agent_error_last"],
            agent_error_avg=snap["agent_error_avg"],
            per_arc=np.zeros((2, 0)),
        ),
        snap,
    )
    layout = Recording()
    gathered(rs, layout, n_arcs=20, holds=True)
    gather = {f.name for f in fields(RunState) if f.metadata["gathered"] and getattr(rs, f.name) is not None}
    axes = [axis for kind, axis, _ in layout.asked if kind == "agents"]
    expected = []
    for f in fields(RunState):
        if f.name in gather and f.metadata["rows"] == AGENTS:
            value = getattr(rs, f.name)
            expected += [f.metadata["axis"]] * (len(value) if isinstance(value, tuple | dict) else 1)
    assert axes == expected
    assert [kind for kind, *_ in layout.asked].count("arcs") == 1


def test_a_snapshot_continues_the_run_bit_for_bit():
    saved, whole, _ = snapshots_of_a_run(loss=0.3, burst=2)
    _, again, _ = snapshots_of_a_run(resume=saved[0], loss=0.3, burst=2)
    for name, x in whole.metrics.items():
        assert_array_equal(again.metrics[name], x, err_msg=name)
    assert_array_equal(again.w_last, whole.w_last)


def test_a_dgtd_run_builds_its_channel_once(tmp_path, monkeypatch):
    from dgtd import config
    from dgtd.cli import main

    built = []
    original = config.channel_for

    def counting(*args, **kwargs):
        built.append(1)
        return original(*args, **kwargs)

    monkeypatch.setattr(config, "channel_for", counting)
    main(
        [
            "run",
            "paper-example-1",
            "-T",
            "50",
            "--loss",
            "0.2",
            "--backend",
            "numpy",
            "--no-plots",
            "--no-progress",
            "--out",
            str(tmp_path / "out"),
        ]
    )
    assert len(built) == 1


def test_the_snapshot_is_made_from_the_declaration_alone():
    """A field added to `RunState` is saved without touching `snapshot`: it walks the declared fields."""
    import inspect

    source = inspect.getsource(state.snapshot) + inspect.getsource(state.restore) + inspect.getsource(state.gathered)
    assert "fields(RunState)" in source
    for name in ("agent_error_last", "tail_base", "sum_trace", "messages", "per_arc"):
        assert name not in source
