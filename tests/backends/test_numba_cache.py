"""Cached kernels load without numba's registry refresh, and a cache miss still compiles from a refreshed context."""

import contextlib
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import cli_env
from numba.core.runtime import rtsys

from dgtd.backends.compiled import cache as numba_cache


class FakeContext:
    def __init__(self):
        self.refreshed = 0

    def refresh(self):
        self.refreshed += 1


class FakeCache:
    """What `_load_without_refresh` uses of a numba cache: a hit returns the stored overload, a miss None."""

    def __init__(self, stored):
        self.stored = stored

    def _guard_against_spurious_io_errors(self):
        return contextlib.nullcontext()

    def _load_overload(self, sig, target_context):
        return self.stored.get(sig)


def test_hit_loads_without_refresh_and_miss_refreshes_before_compiling(monkeypatch):
    monkeypatch.setattr(rtsys, "initialize", lambda ctx: None)  # the fake context has no runtime to start
    cache, ctx = FakeCache({"sig": "overload"}), FakeContext()
    assert numba_cache._load_without_refresh(cache, "sig", ctx) == "overload"
    assert ctx.refreshed == 0
    assert numba_cache._load_without_refresh(cache, "other", ctx) is None
    assert ctx.refreshed == 1  # numba compiles next, with every typing and lowering registered


def test_load_quickly_leaves_dispatchers_without_these_internals_alone():
    class NoCache:
        _cache = object()

    d = NoCache()
    numba_cache.load_quickly(d)
    assert not hasattr(d._cache, "load_overload")


SECOND_PROCESS = """
import sys
import numpy as np
from dgtd.scenarios import get_scenario
from dgtd.run.loop import RunSettings, run
from dgtd.sources.model import Sampling
sc = get_scenario("paper-example-1")
res = run(sc.problem, sc.network, sc.algorithm, Sampling(), RunSettings(iterations=500, seeds=2, checkpoints=2,
          backend="numba"))
np.save(sys.argv[1], res.w_last)
print("refreshed" if "numba.np.linalg" in sys.modules else "not refreshed")
"""


def test_a_second_process_loads_the_cached_kernel_without_refresh(tmp_path):
    """The first process may compile (a cold cache); the second loads the kernel from the cache without importing
    numba's registries (numba.np.linalg is one of them) and gets the same numbers bit for bit."""
    outs = []
    for k in range(2):
        out = tmp_path / f"w{k}.npy"
        r = subprocess.run(
            [sys.executable, "-c", SECOND_PROCESS, str(out)], capture_output=True, text=True, env=cli_env()
        )
        assert r.returncode == 0, r.stderr
        outs.append((r.stdout.strip(), np.load(out)))
    assert outs[1][0] == "not refreshed"
    np.testing.assert_array_equal(outs[0][1], outs[1][1])


EDITED_HELPER = """
import sys
import numpy as np
from dgtd.algorithms import TD0
from dgtd.scenarios import get_scenario
from dgtd.run.loop import RunSettings, run
from dgtd.sources.model import Sampling
sc = get_scenario("paper-example-1")
res = run(sc.problem, sc.network, TD0(), Sampling(), RunSettings(iterations=200, seeds=1, checkpoints=1))
print(repr(float(res.w_last.sum())))
"""


@pytest.mark.slow  # compiles a kernel twice in a copy of the package: 8 s
def test_editing_a_helper_module_recompiles_the_kernels_that_inline_it(tmp_path):
    """numba keys a cached kernel by its own file; editing TD(0)'s arithmetic (`dgtd.algorithms.td0.TD0.terms`),
    which the driver inlines, must still change what a fresh process computes (the compiled package clears its cache
    when any module of it or of the algorithms changed), and an unchanged package loads from the cache."""
    import shutil
    from pathlib import Path

    src = tmp_path / "src"
    shutil.copytree(
        Path(__file__).resolve().parents[2] / "src" / "dgtd", src / "dgtd", ignore=shutil.ignore_patterns("__pycache__")
    )
    env = {**cli_env(), "PYTHONPATH": str(src)}

    def value() -> str:
        r = subprocess.run([sys.executable, "-c", EDITED_HELPER], capture_output=True, text=True, env=env)
        assert r.returncode == 0, r.stderr
        return r.stdout.strip()

    before = value()
    assert value() == before
    helper = src / "dgtd" / "algorithms" / "td0.py"
    text = helper.read_text()
    line = "        return (ratio_delta * phi,)\n"
    assert line in text
    helper.write_text(text.replace(line, line.replace("(ratio_delta *", "(0.5 * ratio_delta *")))
    assert value() != before


def test_the_refresh_clears_the_folders_numba_caches_in_under_numba_cache_dir(tmp_path, monkeypatch):
    """With NUMBA_CACHE_DIR set, numba keeps a module's kernels in <dir>/<folder>_<sha1 of its path>, not in a mirror of
    the path: the refresh must clear those, or a kernel compiled before an edit of an inlined helper (an algorithm's
    arithmetic, the step's template) is loaded after it, stale (seen: wrong numbers, then a crash)."""
    from numba.core.caching import UserProvidedCacheLocator

    import dgtd.backends.compiled as compiled
    from dgtd.backends.compiled import driver

    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr("numba.core.config.CACHE_DIR", str(tmp_path))
    where = UserProvidedCacheLocator(driver._seeds, driver.__file__).get_cache_path()
    assert any(str(d) == where for d in compiled._cache_dirs()), (where, compiled._cache_dirs())
    stale = Path(where) / "driver._seeds_dgtd-65.py311.nbi"
    stale.parent.mkdir(parents=True, exist_ok=True)
    stale.write_text("stale")
    monkeypatch.setattr(compiled, "_STAMP", "test-stamp.sha256")  # no stamp yet: as after an edit
    compiled._refresh_cache()
    assert not stale.exists()
