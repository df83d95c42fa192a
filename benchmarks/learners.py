"""Learners on the NumPy, compiled and JAX backends (`dgtd learn --backend numpy|numba|jax`): seconds a step,
measured interleaved (this machine is shared: each round times every backend back to back, the range over rounds is
quoted), after one warm-up run a backend that compiles (or loads) its kernels. Every run is what `dgtd learn` runs.
Usage: python benchmarks/learners.py [--rounds 3] [--backends numpy,numba,jax]"""

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
    parser.add_argument("--backends", default="numpy,numba", help="the first is the one the others are compared with")
    args = parser.parse_args()
    backends = args.backends.split(",")
    columns = "".join(f"{b + ' ms/step':>18}" for b in backends)
    speed_ups = "".join(f"{b + ' speed-up':>16}" for b in backends[1:])
    print(f"{'run':<30}{columns}{speed_ups}")
    for label, task, options in CASES:
        job = resolve_learning(task, options)
        short = SimpleNamespace(**{**vars(job), "settings": dataclasses.replace(job.settings, iterations=2)})
        for backend in backends[1:]:
            seconds_a_step(short, backend)  # the kernels compiled or loaded, once
        rounds = [[seconds_a_step(job, b) * 1e3 for b in backends] for _ in range(args.rounds)]
        times = list(zip(*rounds))
        ratios = [[r[0] / r[i] for r in rounds] for i in range(1, len(backends))]
        print(
            f"{label:<30}"
            + "".join(f"{f'{min(t):.3g}-{max(t):.3g}':>18}" for t in times)
            + "".join(f"{f'{min(x):.2g}-{max(x):.2g}x':>16}" for x in ratios),
            flush=True,
        )


if __name__ == "__main__":
    main()
