"""Loading the compiled kernels from numba's disk cache without numba's start-up of its compiler.

Before numba loads a cached kernel it refreshes its target context: it imports and registers the typing and
lowering of everything numba can compile (about 0.4 s, most of a second run's start). Machine code loaded from
the cache needs none of it, only numba's runtime (NRT) for the arrays a kernel allocates. So the kernels here
load with the runtime alone; on a cache miss the refresh happens before numba compiles, as it would have, and
numba's compiler refreshes the context itself before any compilation in the process.
"""

from __future__ import annotations

from functools import partial


def _load_without_refresh(cache, sig, target_context):
    """`numba.core.caching.Cache.load_overload` less the registry refresh when the cache holds ``sig``."""
    from numba.core.runtime import rtsys

    rtsys.initialize(target_context)  # once per process: the runtime the loaded code links against
    with cache._guard_against_spurious_io_errors():
        data = cache._load_overload(sig, target_context)
    if data is None:  # a miss: numba compiles next, from a refreshed context as usual
        target_context.refresh()
    return data


def load_quickly(*dispatchers) -> None:
    """Let these cached dispatchers load from disk without the registry refresh. Kept as numba's own loader on
    any numba whose cache lacks the internals used here."""
    for dispatcher in dispatchers:
        cache = getattr(dispatcher, "_cache", None)
        if cache is None or not all(hasattr(cache, n) for n in ("_load_overload", "_guard_against_spurious_io_errors")):
            continue
        cache.load_overload = partial(_load_without_refresh, cache)
