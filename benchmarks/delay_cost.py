"""What --delay D costs: seconds of `dgtd run paper-example-1 -T 2000` at delays up to the largest allowed, on the
NumPy and the compiled backends, in interleaved rounds (this machine is shared: the median of each and the range of
the paired ratios to D = 0, a run without --delay, are what to read): the whole command as a user times it, and the
loop alone (after a warm-up; the default 10 seeds).

    python benchmarks/delay_cost.py [--rounds 3] [--delays 0,5,200,5000,10000] [--iterations 2000]

A message is kept in the slot of the step it arrives at and each step reads one slot, so the ratios stay near 1 at
any D (they were 8 at D = 200 and 160 at D = 5 000 on NumPy when every slot was copied and read each step)."""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time

import numpy as np

import dgtd
from dgtd.channels import Imperfect, Lossy, Perfect
from dgtd.cli.bench import time_run
from dgtd.config import RunSettings


def command_seconds(backend: str, delay: int, iterations: int) -> float:
    """Wall seconds of the whole `dgtd run` (start-up, setup, loop, results; no figures)."""
    with tempfile.TemporaryDirectory() as out:
        command = [sys.executable, "-m", "dgtd.cli", "run", "paper-example-1", "-T", str(iterations), "--out", out]
        command += ["--backend", backend, "--no-plots", "--no-progress"] + (["--delay", str(delay)] if delay else [])
        start = time.perf_counter()
        subprocess.run(command, check=True, capture_output=True)
        return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--delays", default="0,5,200,5000,10000")
    parser.add_argument("--iterations", type=int, default=2000)
    args = parser.parse_args()
    sc = dgtd.scenario("paper-example-1")
    problem, network, algorithm = sc.problem, sc.network, sc.algorithm
    arcs = 2 * network.n_edges
    delays = [int(d) for d in args.delays.split(",")]
    print("| backend | D | command, s (median) | ratio to D = 0 (range) | loop, s (median) | ratio to D = 0 (range) |")
    print("|---|---|---|---|---|---|")
    for backend in ("numpy", "numba"):
        whole: dict[int, list[float]] = {d: [] for d in delays}
        loop: dict[int, list[float]] = {d: [] for d in delays}
        for _ in range(args.rounds):
            for d in delays:  # D = 0: what a run without --delay gets, the perfect channel
                channel = Imperfect(Lossy(np.zeros(arcs)), delay=d) if d else Perfect()
                seeds = RunSettings().seeds
                loop[d] += time_run(problem, network, algorithm, seeds, args.iterations, backend, 1, channel)
                whole[d].append(command_seconds(backend, d, args.iterations))
        for d in delays:
            cells = []
            for secs in (whole, loop):
                ratio = np.array(secs[d]) / np.array(secs[delays[0]])
                cells += [f"{np.median(secs[d]):.3f}", f"{ratio.min():.2f}-{ratio.max():.2f}"]
            print(f"| {backend} | {d} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
