"""Checkpoints of a long run on disk: one .npz holding a loop snapshot (`dgtd.run.loop.snapshot`) exactly.

Arrays are stored as binary .npz entries, so every float comes back bit for bit; everything else (step,
checkpoint index, the streams' bit-generator states with their 128-bit integers, the run's config) goes
into one JSON entry. Nothing is pickled. The file is written atomically, so a run killed while saving
leaves the previous checkpoint intact.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np

from dgtd.errors import DgtdInputError
from dgtd.files import read_npz
from dgtd.run.results import atomic_write

FORMAT = 3  # 3: the channel's state (message and bit counts); 2 counted messages in the loop; 1 kept a second sum


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


def save_checkpoint(path: Path, snap: dict, config: dict) -> None:
    """Write ``snap`` and the run's resolved ``config`` to ``path`` atomically."""
    arrays: dict = {}
    meta = {"format": FORMAT, "config": config, "snapshot": _split(snap, "s", arrays)}
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
        raise DgtdInputError(f"checkpoint {path} has format {meta.get('format')}, this dgtd reads {FORMAT}; {fix}")
    return _join(meta["snapshot"], arrays), meta["config"]
