"""The compiled backend (numba): one driver for every algorithm (`dgtd.backends.compiled.driver`) and one per-agent
step per algorithm in `dgtd.backends.compiled.steps`, registered by the algorithm's name
(`dgtd.backends.compiled.step.register`); an algorithm without one runs on the reference backend.

The driver has the contract of `dgtd.backends.reference.run_block`: ``block(ctx, state, channel, w_sum, alphas, blk)
-> (state, channel, w_sum)``, the same samples and the same arithmetic, so the two agree to rounding (tested for every
algorithm). Kernels are compiled on first use and cached on disk (``cache=True``).

numba keys a cached kernel by the file that defines it only (a hash of its text), so editing a step or a helper it
inlines from another module of this package would leave the driver stale. `_refresh_cache` keeps a digest of every
module here beside numba's cache files and, when any module changed, deletes the package's cache files before the
steps are imported, so that numba compiles them all again.
"""

from __future__ import annotations

import hashlib
import importlib
import os
import pkgutil
from pathlib import Path

_HERE = Path(__file__).resolve().parent
_STAMP = "dgtd-sources.sha256"


def _cache_dirs() -> list[Path]:
    """Where numba keeps the cache files of this package's modules: each folder's __pycache__, or its mirror under
    NUMBA_CACHE_DIR."""
    folders = sorted({p.parent for p in _sources()})
    root = os.environ.get("NUMBA_CACHE_DIR")
    if root:
        return [Path(root) / folder.relative_to(folder.anchor) for folder in folders]
    return [folder / "__pycache__" for folder in folders]


def _sources() -> list[Path]:
    return sorted(p for p in _HERE.rglob("*.py") if "__pycache__" not in p.parts)


def _refresh_cache() -> None:
    """Delete the package's numba cache files when the digest of its modules differs from the stamp left by the
    last compilation (a no-op where the cache is not writable: an installed copy is rewritten whole on upgrade)."""
    digest = hashlib.sha256()
    for p in _sources():
        digest.update(p.relative_to(_HERE).as_posix().encode() + b"\0" + p.read_bytes())
    dirs = _cache_dirs()
    stamp = dirs[0] / _STAMP
    try:
        if stamp.exists() and stamp.read_text() == digest.hexdigest():
            return
        for folder in dirs:
            for f in list(folder.glob("*.nbi")) + list(folder.glob("*.nbc")):
                f.unlink(missing_ok=True)
        stamp.parent.mkdir(parents=True, exist_ok=True)
        stamp.write_text(digest.hexdigest())
    except OSError:
        pass


_refresh_cache()

from dgtd.backends.compiled import steps as _steps  # noqa: E402  (after the cache is refreshed)
from dgtd.backends.compiled.driver import run_block  # noqa: E402
from dgtd.backends.compiled.step import STEPS  # noqa: E402

for _module in pkgutil.iter_modules(_steps.__path__):
    importlib.import_module(f"{_steps.__name__}.{_module.name}")

__all__ = ["STEPS", "run_block"]
