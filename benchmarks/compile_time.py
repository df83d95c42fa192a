"""How long the compiled kernels take to compile on a machine that has none cached: a first `dgtd run
paper-example-1` (what its last line reports as "kernels X s"), then each algorithm's kernels in both
layouts, each in a fresh process over one empty numba cache (so that what the algorithms share, the samplers, is
compiled once, as on a user's machine). Usage: python benchmarks/compile_time.py [--algorithms all|dgtd,...]"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time

ONE_ALGORITHM = """
import sys, time
from dgtd.backends.compiled import driver
from dgtd.config import AlgorithmConfig, Output, ProblemConfig, RunConfig, RunLength
import dgtd
driver.LAYOUT = sys.argv[2]
start = time.perf_counter()
dgtd.execute(RunConfig(ProblemConfig(scenario="paper-example-1"), algorithm=AlgorithmConfig(name=sys.argv[1]),
    run=RunLength(iterations=200), output=Output(out=sys.argv[3], plots=False, progress=False, overwrite=True)))
print(time.perf_counter() - start)
"""


def first_run(cache: str, out: str) -> float:
    """The kernels' compile time a first `dgtd run paper-example-1` reports."""
    env = dict(os.environ, NUMBA_CACHE_DIR=cache)
    text = subprocess.run(
        [sys.executable, "-m", "dgtd.cli", "run", "paper-example-1", "--out", out, "--no-plots", "--no-progress"],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    return float(re.search(r"kernels ([\d.]+) s", text).group(1))  # the last line: (... kernels X s, run ...)


def main() -> None:
    from dgtd.algorithms import ALGORITHMS

    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--algorithms", default="all")
    names = list(ALGORITHMS) if parser.parse_args().algorithms == "all" else parser.parse_args().algorithms.split(",")
    with tempfile.TemporaryDirectory() as tmp:
        cache = os.path.join(tmp, "numba")
        print(f"first dgtd run paper-example-1: kernels compiled in {first_run(cache, os.path.join(tmp, 'p')):.1f} s")
        total = 0.0
        for name in names:
            for layout in ("seeds", "agents"):
                start = time.perf_counter()
                subprocess.run(
                    [sys.executable, "-c", ONE_ALGORITHM, name, layout, os.path.join(tmp, f"{name}-{layout}")],
                    env=dict(os.environ, NUMBA_CACHE_DIR=cache),
                    check=True,
                    capture_output=True,
                )
                seconds = time.perf_counter() - start
                total += seconds
                print(f"{name:14s} {layout:6s} {seconds:6.1f} s (a process: start, compile, 200 steps)", flush=True)
        print(f"every algorithm, both layouts: {total:.0f} s")


if __name__ == "__main__":
    main()
