"""Checkpoints of a long run on disk: one .npz holding a run's snapshot (`dgtd.run.state.snapshot`) exactly, or, for
agents spread over the ranks of an MPI job, a shard a rank.

Arrays are stored as binary .npz entries, so every float comes back bit for bit; everything else (step,
checkpoint index, the step the keyed streams are at, the run's config) goes into one JSON entry. No generator's
state is saved: every random number is keyed by its seed, purpose, entity and step (`dgtd.streams`).
Nothing is pickled. The file is written atomically, so a run killed while saving leaves the previous checkpoint
intact.

Spread over R ranks, each rank saves the rows it holds (its own agents' state, sums and errors, the arcs into them,
its trajectories' states), with their ids: ranks 1 .. R - 1 into ``checkpoint.K.r.npz`` (K: the step), then rank 0
into ``checkpoint.npz``, naming the others, which is the commit of the set (a run killed before it continues from the
previous set, whose shards go only after). `assemble` takes any agents' and arcs' rows from the shards, so a run
resumes on any number of ranks, or in one process, with the numbers of an uninterrupted run.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np

from dgtd.channels.base import per_arc_fields
from dgtd.errors import DgtdInputError
from dgtd.files import read_npz
from dgtd.run.atomic import atomic_write
from dgtd.run.state import RunState, declared

# 5: late messages kept in the slot of the step they arrive at (4 kept them in that of the step they were sent at:
# a format-4 checkpoint with messages in flight cannot continue, one without can); 4: keyed random streams (a
# source's and a channel's state is the step they are at); 3: sequential PCG64 streams and the channel's state
# (message and bit counts); 2 counted messages in the loop; 1 kept a second sum
FORMAT = 5
_WRITTEN_BY = {1: "dgtd before the channels", 2: "dgtd before the channels", 3: "dgtd with sequential random streams"}


def _split(obj, key: str, arrays: dict):
    """JSON-ready copy of ``obj`` with every ndarray moved into ``arrays`` under a path-like key."""
    if isinstance(obj, np.ndarray):
        arrays[key] = obj
        return {"__array__": key}
    if isinstance(obj, dict):
        return {str(k): _split(v, f"{key}/{k}", arrays) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_split(v, f"{key}/{i}", arrays) for i, v in enumerate(obj)]
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def _join(obj, arrays):
    if isinstance(obj, dict):
        if set(obj) == {"__array__"}:
            return arrays[obj["__array__"]]
        return {k: _join(v, arrays) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_join(v, arrays) for v in obj]
    return obj


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("dgtd")
    except PackageNotFoundError:
        return "(not installed)"


def save_checkpoint(path: Path, snap: dict, config: dict, comm=None) -> None:
    """Write ``snap`` and the run's resolved ``config`` to ``path`` atomically. ``comm``: the ranks of a run whose
    agents are spread, each calling this with the snapshot of its rows (a collective; see the module's docstring)."""
    path = Path(path)
    if comm is None or comm.Get_size() == 1:
        _write(path, snap, config, [])
        drop_shards(path)
        return
    r, R, k = comm.Get_rank(), comm.Get_size(), int(snap["k"])
    names = [f"{path.stem}.{k}.{j}.npz" for j in range(1, R)]
    if r > 0:
        _write(path.parent / names[r - 1], snap, None, [])
    comm.Barrier()  # every shard is on disk ...
    if r == 0:
        _write(path, snap, config, names)  # ... before the set is committed
        drop_shards(path, keep=names)


def _write(path: Path, snap: dict, config: dict | None, shards: list) -> None:
    arrays: dict = {}
    meta = {
        "format": FORMAT,
        "written_by": f"dgtd {_version()}",
        "config": config,
        "shards": shards,
        "snapshot": _split(snap, "s", arrays),
    }
    buf = io.BytesIO()
    np.savez(buf, __meta__=np.array(json.dumps(meta)), **arrays)
    atomic_write(Path(path), buf.getvalue())


def drop_shards(path: Path, keep=()) -> None:
    """Remove the other ranks' shards of checkpoint ``path`` but those named ``keep``."""
    path = Path(path)
    for shard in path.parent.glob(f"{path.stem}.*.*.npz"):
        if shard.name not in keep:
            shard.unlink(missing_ok=True)


def remove_checkpoint(path: Path) -> None:
    """Remove checkpoint ``path`` and its shards (nothing is left to resume)."""
    Path(path).unlink(missing_ok=True)
    drop_shards(path)


FIX = "start the run afresh with --overwrite (or delete it)"


def load_checkpoint(path: Path) -> tuple[dict, dict]:
    """(snapshot, config) from a checkpoint file, or a `DgtdInputError` saying what is wrong with it. A spread run's
    snapshot is rank 0's, with ``shards``: the paths of the other ranks' (`assemble` reads them)."""
    path = Path(path)
    meta, snapshot = _read(path, "checkpoint")
    shards = [path.parent / name for name in meta.get("shards") or []]
    missing = [s.name for s in shards if not s.exists()]
    if missing:
        raise DgtdInputError(f"checkpoint {path} names shards that are not there ({', '.join(missing)}); {FIX}")
    return ({**snapshot, "shards": shards} if shards else snapshot), meta["config"]


def _read(path: Path, what: str) -> tuple[dict, dict]:
    arrays = read_npz(path, what, FIX, required=("__meta__",))
    try:
        meta = json.loads(str(arrays.pop("__meta__")))
    except ValueError:
        raise DgtdInputError(f"{what} {path} is damaged (its description is not JSON); {FIX}") from None
    snap = _join(meta.get("snapshot", {}), arrays)
    if meta.get("format") != FORMAT and not (meta.get("format") == 4 and not _in_flight(snap)):
        who = meta.get("written_by") or _WRITTEN_BY.get(meta.get("format"), f"checkpoint format {meta.get('format')}")
        raise DgtdInputError(
            f"{what} {path} was written by {who} (format {meta.get('format')}); this dgtd (format {FORMAT}, keyed "
            f"random streams, late messages by arrival) cannot continue it with the same numbers: {FIX}"
        )
    return meta, snap


def _in_flight(snap) -> bool:
    """Whether a snapshot holds slots for late messages (a run with --delay)."""
    channel = snap.get("channel") if isinstance(snap, dict) else None
    return bool(isinstance(channel, dict) and np.size(channel.get("pending", ())))


def assemble(
    resume: dict, n_agents: int, n_arcs: int, agents=None, arcs=None, trajectories=None, state=RunState
) -> dict:
    """``resume`` with its agents' rows those of ``agents``, its arcs' those of ``arcs`` and its trajectories' states
    those of the agents ``trajectories`` (ids in the whole network; None: every agent's, every arc's, in order),
    taken by id from whichever shard holds them: how a rank, or one process, continues a checkpoint written by any
    number of ranks. ``state`` the record the snapshot is of (`dgtd.run.state.declared`)."""
    shards = resume.get("shards") or []
    if not shards and "agents" not in resume and agents is None and arcs is None and trajectories is None:
        return resume  # one process continuing a one-process checkpoint
    wanted = {
        "agents": np.arange(n_agents) if agents is None else np.asarray(agents),
        "arcs": np.arange(n_arcs) if arcs is None else np.asarray(arcs),
        "source": np.arange(n_agents) if trajectories is None else np.asarray(trajectories),
    }
    out = {key: (dict(v) if isinstance(v, dict) else v) for key, v in resume.items() if key != "shards"}
    filled: dict = {}
    for part in [resume, *shards]:
        part = part if isinstance(part, dict) else _read(Path(part), "checkpoint shard")[1]
        for keys, axis, kind in _rows_of(part, state):
            x = part[keys[0]] if len(keys) == 1 else part[keys[0]][keys[1]]
            ids = part.get(kind) if kind != "source" else part["source"].get("agents")
            if kind == "source" and ids is None and (x.shape[1] == 1 or trajectories is None):
                _put(out, keys, x)  # the one shared trajectory, or every agent's for one process
                filled[keys] = (x, np.ones(1, bool))
                continue
            ids = np.arange(x.shape[axis]) if ids is None else np.asarray(ids)
            want = wanted[kind]
            if keys not in filled:
                shape = list(x.shape)
                shape[axis] = len(want)
                filled[keys] = (np.zeros(shape, x.dtype), np.zeros(len(want), bool))
                _put(out, keys, filled[keys][0])
            dest, got = filled[keys]
            where = np.full(max(int(ids.max(initial=-1)), int(want.max(initial=-1))) + 1, -1)
            where[ids] = np.arange(len(ids))
            take = where[want]
            ok = take >= 0
            np.moveaxis(dest, axis, 0)[ok] = np.moveaxis(x, axis, 0)[take[ok]]
            got |= ok
    short = [keys[-1] for keys, (_, got) in filled.items() if not got.all()]
    if short:
        raise DgtdInputError(f"the checkpoint's shards do not hold every row of {', '.join(short)}; {FIX}")
    return out


def _rows_of(snap: dict, state):
    """(keys, axis, kind) of every array of ``snap`` holding agents' or arcs' rows, as ``state`` declares them."""
    agent_axes, arc_fields = declared(state)
    for name, axis in agent_axes.items():
        value = snap.get(name)
        if isinstance(value, dict):
            yield from (((name, f), axis, "agents") for f in value)
        elif value is not None:
            yield (name,), axis, "agents"
    for name in arc_fields:
        value = snap.get(name)
        if isinstance(value, dict):  # a channel's state: the per-arc fields it holds (the others empty placeholders)
            yield from (((name, f), 1, "arcs") for f in per_arc_fields(value))
        elif value is not None and np.ndim(value) >= 2 and value.shape[0] and value.shape[1]:
            yield (name,), 1, "arcs"
    if isinstance(snap.get("source"), dict) and snap["source"].get("current") is not None:
        yield ("source", "current"), 1, "source"


def _put(out: dict, keys: tuple, x) -> None:
    if len(keys) == 1:
        out[keys[0]] = x
    else:
        out[keys[0]][keys[1]] = x
