"""Files written atomically (a temporary file, then a rename) with the mode the user's umask gives new files, and JSON
as a file holds it (no NaN)."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path


def file_mode() -> int:
    """The mode a new file gets under the user's umask (what open() would give it): a temporary file is made 0600."""
    mask = os.umask(0o022)
    os.umask(mask)
    return 0o666 & ~mask


def atomic_write(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` so that a crash or Ctrl-C leaves either the old file or the new one, never half;
    the file gets the mode the user's umask gives new files."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fchmod(f.fileno(), file_mode())
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def json_ready(obj):
    """``obj`` with NaN and infinities (a diverged seed's numbers) as null, which standard JSON allows."""
    if isinstance(obj, float):
        return obj if obj == obj and abs(obj) != float("inf") else None
    if isinstance(obj, dict):
        return {k: json_ready(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_ready(v) for v in obj]
    return obj


def json_bytes(obj) -> bytes:
    """Standard JSON (no NaN), as a file holds it."""
    return (json.dumps(json_ready(obj), indent=2, allow_nan=False) + "\n").encode()


def atomic_write_json(path: Path, obj) -> None:
    """Standard JSON (no NaN), written atomically."""
    atomic_write(path, json_bytes(obj))
