"""The compiled backend (numba): one kernel file per algorithm in `dgtd.backends.compiled.kernels`, registered by the
algorithm's name with `kernel`; an algorithm without one runs on the reference backend.

A kernel has the contract of `dgtd.backends.reference.run_block`: ``block(ctx, state, w_sum, alphas, blk) ->
(state, w_sum)``, the same samples and the same arithmetic, so the two agree to rounding (tested for every
algorithm). Kernels are compiled once and cached on disk (``cache=True``).

numba keys a cached kernel by the file that defines it only, so editing a helper it inlines from another module of
this package would leave it stale. `_refresh_cache_stamp` keeps a digest of every module here beside numba's cache
and, when any of them changed, touches them all before they are imported, so that numba recompiles everything.
"""

from __future__ import annotations

import hashlib
import importlib
import os
import pkgutil
import time
from pathlib import Path

KERNELS: dict = {}
"""Algorithm name -> block kernel."""

_HERE = Path(__file__).resolve().parent
_STAMP = "sources.sha256"


def kernel(name: str):
    """Register the decorated function as the compiled block kernel of algorithm ``name``."""

    def register(fn):
        KERNELS[name] = fn
        return fn

    return register


def _sources() -> list[Path]:
    return sorted(p for p in _HERE.rglob("*.py") if "__pycache__" not in p.parts)


def _refresh_cache_stamp() -> None:
    """Touch every module of the package when their digest differs from the stamp of the last import (a no-op
    where the package is not writable: an installed copy is rewritten whole on upgrade, new stamps and all)."""
    files = _sources()
    digest = hashlib.sha256(b"".join(p.relative_to(_HERE).as_posix().encode() + p.read_bytes() for p in files))
    cache_dir = Path(os.environ.get("NUMBA_CACHE_DIR") or _HERE / "__pycache__")
    stamp = cache_dir / f"{hashlib.sha256(str(_HERE).encode()).hexdigest()[:12]}-{_STAMP}"  # one per checkout
    try:
        if stamp.exists() and stamp.read_text() == digest.hexdigest():
            return
        now = time.time()
        for p in files:
            os.utime(p, (now, now))
        cache_dir.mkdir(parents=True, exist_ok=True)
        stamp.write_text(digest.hexdigest())
    except OSError:
        pass


_refresh_cache_stamp()

from dgtd.backends.compiled import kernels as _kernels  # noqa: E402  (after the stamp: numba reads file times)

for _module in pkgutil.iter_modules(_kernels.__path__):
    importlib.import_module(f"{_kernels.__name__}.{_module.name}")
