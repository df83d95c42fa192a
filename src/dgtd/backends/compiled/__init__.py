"""The compiled backend (numba): one kernel file per algorithm in `dgtd.backends.compiled.kernels`, registered by the
algorithm's name with `kernel`; an algorithm without one runs on the reference backend.

A kernel has the contract of `dgtd.backends.reference.run_block`: ``block(ctx, state, w_sum, alphas, blk) ->
(state, w_sum)``, the same samples and the same arithmetic, so the two agree to rounding (tested for every
algorithm). Kernels are compiled once and cached on disk (``cache=True``).

numba keys a cached kernel by the file that defines it only (a hash of its text), so editing a helper it inlines from
another module of this package would leave it stale. `_refresh_cache` keeps a digest of every module here beside
numba's cache files and, when any module changed, deletes the package's cache files before the kernels are
imported, so that numba compiles them all again.
"""

from __future__ import annotations

import hashlib
import importlib
import os
import pkgutil
from pathlib import Path

KERNELS: dict = {}
"""Algorithm name -> block kernel."""

_HERE = Path(__file__).resolve().parent
_STAMP = "dgtd-sources.sha256"


def kernel(name: str):
    """Register the decorated function as the compiled block kernel of algorithm ``name``."""

    def register(fn):
        KERNELS[name] = fn
        return fn

    return register


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

from dgtd.backends.compiled import kernels as _kernels  # noqa: E402  (after the cache is refreshed)

for _module in pkgutil.iter_modules(_kernels.__path__):
    importlib.import_module(f"{_kernels.__name__}.{_module.name}")
