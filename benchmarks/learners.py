"""Learners on the NumPy and the compiled backends (`dgtd learn --backend numpy|numba`): seconds a step, measured in
interleaved pairs (this machine is shared: each round times both backends back to back, the range over rounds is
quoted), after one warm-up run that compiles (or loads) the kernels. Every run is what `dgtd learn` runs.
Usage: python benchmarks/learners.py [--rounds 3]"""

from __future__ import annotations

import argparse
import dataclasses
import time
from types import SimpleNamespace

from dgtd.learning import resolve_learning
from dgtd.run.learn import learn

CASES = [  # (label, task, options): the learning runs of docs/control.md
    ("pull-away, networked, DGTD", "pull-away", {"iterations": 4000, "seeds": 2, "checkpoints": 1}),
    ("zhang-20, networked, DGTD", "zhang-20", {"iterations": 2000, "seeds": 2, "checkpoints": 1}),
    ("zhang-20, action values", "zhang-20", {"iterations": 1000, "seeds": 2, "checkpoints": 1, "values": "action"}),
    ("factored 1000, regression", "factored", {"iterations": 20, "seeds": 1, "checkpoints": 1, "agents": 1000}),
    (
        "factored 1000, independent",
        "factored",
        {"iterations": 400, "seeds": 1, "checkpoints": 1, "agents": 1000, "actor": "independent"},
    ),
    (
        "factored 1000, neighbourhood",
        "factored",
        {"iterations": 400, "seeds": 1, "checkpoints": 1, "agents": 1000, "team_reward": "neighbourhood"},
    ),
    (
        "factored 10000, neighbourhood",
        "factored",
        {"iterations": 100, "seeds": 1, "checkpoints": 1, "agents": 10_000, "team_reward": "neighbourhood"},
    ),
]


def seconds_a_step(job, backend: str) -> float:
    settings = dataclasses.replace(job.settings, backend=backend)
    start = time.perf_counter()
    learn(job.mdp, job.network, job.critic, job.actor, settings, job.channel)
    return (time.perf_counter() - start) / settings.iterations


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    print(f"{'run':<30}{'numpy ms/step':>16}{'numba ms/step':>16}{'speed-up':>14}")
    for label, task, options in CASES:
        job = resolve_learning(task, options)
        short = SimpleNamespace(**{**vars(job), "settings": dataclasses.replace(job.settings, iterations=2)})
        seconds_a_step(short, "numba")  # the kernels compiled or loaded, once
        pairs = [(seconds_a_step(job, "numpy"), seconds_a_step(job, "numba")) for _ in range(args.rounds)]
        numpy = [p[0] * 1e3 for p in pairs]
        numba = [p[1] * 1e3 for p in pairs]
        ratios = [a / b for a, b in pairs]
        print(
            f"{label:<30}{f'{min(numpy):.3g}-{max(numpy):.3g}':>16}{f'{min(numba):.3g}-{max(numba):.3g}':>16}"
            f"{f'{min(ratios):.2g}-{max(ratios):.2g}x':>14}",
            flush=True,
        )


if __name__ == "__main__":
    main()
