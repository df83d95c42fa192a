"""Checkpoints of a long run on disk: one .npz holding a loop snapshot (`dgtd.run.loop.snapshot`) exactly.

Arrays are stored as binary .npz entries, so every float comes back bit for bit; everything else (step,
checkpoint index, the step the keyed streams are at, the run's config) goes into one JSON entry. No generator's
state is saved: every random number is keyed by its seed, purpose, entity and step (`dgtd.streams`).
Nothing is pickled. The file is written atomically, so a run killed while saving leaves the previous checkpoint
intact.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np

from dgtd.errors import DgtdInputError
from dgtd.files import read_npz
from dgtd.run.results import atomic_write

# 4: keyed random streams (a source's and a channel's state is the step they are at); 3: sequential PCG64 streams
# and the channel's state (message and bit counts); 2 counted messages in the loop; 1 kept a second sum
FORMAT = 4
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


def save_checkpoint(path: Path, snap: dict, config: dict) -> None:
    """Write ``snap`` and the run's resolved ``config`` to ``path`` atomically."""
    arrays: dict = {}
    meta = {
        "format": FORMAT,
        "written_by": f"dgtd {_version()}",
        "config": config,
        "snapshot": _split(snap, "s", arrays),
    }
    buf = io.BytesIO()
    np.savez(buf, __meta__=np.array(json.dumps(meta)), **arrays)
    atomic_write(Path(path), buf.getvalue())


def load_checkpoint(path: Path) -> tuple[dict, dict]:
    """(snapshot, config) from a checkpoint file, or a `DgtdInputError` saying what is wrong with it."""
    fix = "start the run afresh with --overwrite (or delete it)"
    arrays = read_npz(path, "checkpoint", fix, required=("__meta__",))
    try:
        meta = json.loads(str(arrays.pop("__meta__")))
    except ValueError:
        raise DgtdInputError(f"checkpoint {path} is damaged (its description is not JSON); {fix}") from None
    if meta.get("format") != FORMAT:
        who = meta.get("written_by") or _WRITTEN_BY.get(meta.get("format"), f"checkpoint format {meta.get('format')}")
        raise DgtdInputError(
            f"checkpoint {path} was written by {who} (format {meta.get('format')}); this dgtd (format {FORMAT}, keyed "
            f"random streams) cannot continue it with the same numbers: {fix}"
        )
    return _join(meta["snapshot"], arrays), meta["config"]
