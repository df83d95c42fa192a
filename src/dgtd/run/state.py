"""A run's state between blocks: one record (`RunState`; a learning run's `dgtd.run.learn.Learners`) whose fields are
declared once (`held`), each with what it holds: rows of agents on an axis, entries of arcs, or numbers of the whole
run. From that declaration alone a checkpoint's snapshot is written (`snapshot`) and read back (`restore`), the
shards of spread ranks are put together (`dgtd.run.checkpoint.assemble`, through `declared`), and the final rows are
gathered on the process that writes the results (`gathered`): no list of keys is kept by hand anywhere else."""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np

from dgtd.channels.base import per_arc_fields

AGENTS, ARCS, WHOLE = "agents", "arcs", "whole"


def held(
    rows: str = WHOLE,
    axis: int = 0,
    *,
    gathered: bool = False,
    root_only: bool = False,
    saved: bool = True,
    per_checkpoint: bool = False,
    default=None,
):
    """A state's field: what its arrays hold (``rows`` of agents or arcs on ``axis``, or numbers of the whole run),
    whether the end of the run gathers it whole on the writing process, whether that process alone holds it, whether
    a checkpoint saves it (not what is empty at every checkpoint, or cannot be continued), whether its arrays have a
    row a checkpoint first (a run extended to more steps gets rows for its new checkpoints: `restore`)."""
    meta = dict(rows=rows, axis=axis, gathered=gathered, root_only=root_only, saved=saved)
    meta["per_checkpoint"] = per_checkpoint
    return field(default=default, metadata=meta)


@dataclass
class RunState:
    """Everything a run carries from block to block, as a checkpoint saves it: a run continued from it gives the
    numbers of an uninterrupted run bit for bit. C checkpoints, B seeds; ``n`` the estimates held here (a rank's
    agents, every agent, or 1 for a centralised learner)."""

    k: int = held(default=0)  # the steps taken
    c: int = held(default=0)  # the checkpoints recorded
    seconds: float = held(default=0.0)  # seconds spent before this process took the run up (a resumed run's)
    state: Any = held(AGENTS, 1, gathered=True)  # the algorithm's state (a NamedTuple of (B, n, q) arrays)
    sums: Any = held(AGENTS, 1, gathered=True)  # {"all": the running sum of the estimates w_k (B, n, q)}
    tail_base: Any = held(AGENTS, 1, gathered=True)  # that sum when the tail began
    steps: Any = held()  # (C,) the checkpoints' steps (a run extended to more steps keeps those it had)
    metrics: Any = held(per_checkpoint=True)  # (C, B) each, `dgtd.run.measure.METRICS`
    counts: Any = held(per_checkpoint=True)  # (C, B) each, `dgtd.run.measure.COUNTS`
    agent_error_last: Any = held(AGENTS, 2, gathered=True, per_checkpoint=True)  # (C, B, n)
    agent_error_avg: Any = held(AGENTS, 2, gathered=True, per_checkpoint=True)
    w_trace: Any = held(root_only=True, per_checkpoint=True)  # (C, B, N, q), where small enough
    sum_trace: Any = held(AGENTS, 2, per_checkpoint=True)  # the running sum at each checkpoint, for the tail averages
    messages: Any = held()  # (B,) delivered so far, frozen once a seed diverges
    bits: Any = held()
    per_arc: Any = held(ARCS, 1, gathered=True)  # (B, arcs) deliveries, where the channel counts them
    diverged_at: Any = held()  # (B,) the step a seed diverged at, -1 while it has not
    channel: Any = held(ARCS, 1)  # the channel's state (`dgtd.channels.base.Channel.init`)
    source: dict | None = held()  # the source's stream state, taken at a save
    message_ages: dict | None = held()  # asynchronous ranks' counts of message ages, taken at a save

    @property
    def w_sum(self) -> np.ndarray:
        return self.sums["all"]


def declared(state=RunState) -> tuple[dict, tuple]:
    """({field: its agents' axis} of the fields holding agents' rows, the fields holding arcs' entries) of a state's
    declaration (`RunState`'s by default)."""
    return (
        {f.name: f.metadata["axis"] for f in fields(state) if f.metadata["rows"] == AGENTS},
        tuple(f.name for f in fields(state) if f.metadata["rows"] == ARCS),
    )


AGENT_AXES, ARC_FIELDS = declared(RunState)


def _is_record(x) -> bool:
    return isinstance(x, tuple) and hasattr(x, "_fields")


def _copy(x):
    if _is_record(x):
        return {name: np.array(v) for name, v in x._asdict().items()}
    if isinstance(x, dict):
        return {name: (_copy(v) if isinstance(v, np.ndarray) else v) for name, v in x.items()}
    if isinstance(x, np.ndarray):
        return x.copy()
    return x


def snapshot(rs, layout, seconds: float | None = None) -> dict:
    """The run's state (a declared record: `RunState`, `dgtd.run.learn.Learners`) as a checkpoint holds it (copies):
    every saved field that holds something, the per-arc entries of the arcs ``layout`` reports, and the ids of the
    rows held here (a rank's shard); ``seconds`` spent so far, where given."""
    snap = dict(layout.shard())
    for f in fields(rs):
        x = getattr(rs, f.name)
        if x is None or not f.metadata["saved"]:
            continue
        if f.metadata["rows"] == ARCS:
            x = _reported(x, layout)
        snap[f.name] = _copy(x)
    if seconds is not None:
        snap["seconds"] = float(seconds)
    return snap


def _reported(x, layout):
    """The entries of the arcs into the agents ``layout`` holds, of a channel's state or a per-arc array."""
    if _is_record(x):
        return x._replace(**{name: layout.reported(v) for name, v in per_arc_fields(x).items()})
    return layout.reported(x) if x.size else x


def restore(initial, snap: dict):
    """``initial`` with every field a snapshot holds put back, as the type ``initial`` has it (a record's fields by
    name, an array in its dtype); a field the snapshot lacks (an older checkpoint's) keeps its initial value, and one
    held by the writing process alone stays absent elsewhere. A field with a row a checkpoint (``per_checkpoint``)
    that the snapshot has fewer rows of (a finished run extended to more steps) fills the first rows of the initial
    one, the new checkpoints' rows as they start; one the run no longer keeps (too large now) stays absent."""
    values = {}
    for f in fields(initial):
        x, init = snap.get(f.name), getattr(initial, f.name)
        if x is None or ((f.metadata["root_only"] or f.metadata["per_checkpoint"]) and init is None):
            continue
        if f.metadata["per_checkpoint"]:
            x = {n: _leading(init[n], v) for n, v in x.items()} if isinstance(x, dict) else _leading(init, x)
        values[f.name] = _as(init, x)
    return replace(initial, **values)


def _leading(init: np.ndarray, x) -> np.ndarray:
    """``init`` with its first rows ``x`` (a snapshot's rows of the checkpoints it measured)."""
    out = np.array(init, copy=True)
    out[: np.shape(x)[0]] = x
    return out


def _as(init, x):
    if _is_record(init):
        return init._make(np.array(x[name]) if name in x else v for name, v in init._asdict().items())
    if isinstance(init, np.ndarray):
        return np.array(x, dtype=init.dtype)
    if isinstance(init, bool | int | float):
        return type(init)(x)
    if isinstance(init, dict) and all(isinstance(v, np.ndarray) for v in x.values()):
        return {name: np.array(v) for name, v in x.items()}
    return x


def gathered(rs: RunState, layout, n_arcs: int, holds: bool) -> RunState:
    """The state with every field declared ``gathered`` whole on the process that writes the results (a collective
    where the agents are spread): agents' rows on their axis; the per-arc counts where the channel keeps them
    (``holds``)."""
    values = {}
    for f in fields(RunState):
        x = getattr(rs, f.name)
        if not f.metadata["gathered"] or x is None:
            continue
        if f.metadata["rows"] == ARCS:
            values[f.name] = layout.whole_arcs(x, n_arcs) if holds else x
        elif _is_record(x):
            values[f.name] = x._make(layout.whole(v, f.metadata["axis"]) for v in x)
        elif isinstance(x, dict):
            values[f.name] = {name: layout.whole(v, f.metadata["axis"]) for name, v in x.items()}
        else:
            values[f.name] = layout.whole(x, f.metadata["axis"])
    return replace(rs, **values)
