"""The compiled backend (numba): one driver for every algorithm (`dgtd.backends.compiled.driver`) and each
algorithm's per-agent step, made from its one definition (`dgtd.backends.compiled.step.compiled_step`), by name in
`STEPS` (a user's algorithm in that form gets one too: `step_of`); an algorithm that writes only ``update`` runs on
the reference backend. Each link model of `dgtd.channels` has its compiled twin, registered by name in `TWINS`; a
channel without one runs on the reference backend too (`fallback`).

The driver has the contract of `dgtd.backends.reference.run_block`: ``block(ctx, state, channel, w_sum, alphas, blk)
-> (state, channel, w_sum)``, the same samples and the same arithmetic, so the two agree to rounding (tested for every
algorithm). Kernels are compiled on first use and cached on disk (``cache=True``).

numba keys a cached kernel by the file that defines it only (a hash of its text), so editing an algorithm's arithmetic
or a helper the driver inlines from another module would leave the driver stale. `_refresh_cache` keeps a digest of
every module here and of the algorithms' beside numba's cache files and, when any changed, deletes the package's cache
files before the steps are made, so that numba compiles them all again.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

_HERE = Path(__file__).resolve().parent
_ALGORITHMS = _HERE.parent.parent / "algorithms"
_STAMP = "dgtd-sources.sha256"


def _cache_dirs() -> list[Path]:
    """Where numba keeps the cache files of this package's modules: each folder's __pycache__, or under
    NUMBA_CACHE_DIR the folder numba's own locator names for it (<dir>/<folder>_<sha1 of its path>, not a mirror of
    the path)."""
    from numba.core import config
    from numba.core.caching import UserProvidedCacheLocator

    folders = sorted({p.parent for p in _sources()})
    root = os.environ.get("NUMBA_CACHE_DIR") or getattr(config, "CACHE_DIR", "")
    if root:
        return [Path(root) / UserProvidedCacheLocator.get_suitable_cache_subpath(str(f / "x.py")) for f in folders]
    return [folder / "__pycache__" for folder in folders]


def _sources() -> list[Path]:
    return sorted(p for p in [*_HERE.rglob("*.py"), *_ALGORITHMS.glob("*.py")] if "__pycache__" not in p.parts)


def _refresh_cache() -> None:
    """Delete the package's numba cache files when the digest of its modules differs from the stamp left by the
    last compilation (a no-op where the cache is not writable: an installed copy is rewritten whole on upgrade)."""
    digest = hashlib.sha256()
    for p in _sources():
        digest.update(p.relative_to(_HERE.parent.parent).as_posix().encode() + b"\0" + p.read_bytes())
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

from dgtd.algorithms import ALGORITHMS  # noqa: E402
from dgtd.backends.compiled.driver import run_block  # noqa: E402
from dgtd.backends.compiled.step import CompiledStep, registered_step, source_of, step_of  # noqa: E402
from dgtd.channels import Imperfect, Lossy, Perfect  # noqa: E402

STEPS = {name: registered_step(cls) for name, cls in ALGORITHMS.items()}

# Each link model's compiled twin, tested equal to it: the perfect and lossy links' hearing (`channel`) and draws per
# arc (`sampling`), and the copies the receivers of imperfect links hold (`held`), all driven by `driver`
TWINS = {cls.name: cls for cls in (Perfect, Lossy, Imperfect)}


def fallback(algorithm, channel) -> str | None:
    """Why a run of ``algorithm`` over ``channel`` takes the NumPy reference backend instead (one line), or None
    where this backend runs it."""
    if step_of(algorithm) is None:
        return (
            f"algorithm {algorithm.name!r} writes update alone, not the one definition the compiled backend runs "
            "(dgtd.algorithms.base): it runs on the NumPy reference backend"
        )
    if channel is not None and TWINS.get(channel.name) is not type(channel):
        return (
            f"channel {channel.name!r} has no compiled twin (dgtd.backends.compiled.TWINS): it runs on the NumPy "
            "reference backend"
        )
    return None


__all__ = ["STEPS", "TWINS", "CompiledStep", "fallback", "run_block", "source_of", "step_of"]
