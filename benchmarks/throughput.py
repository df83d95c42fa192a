"""Throughput benchmark: agent-steps per second of both backends on cases A-E (DGTD, or every algorithm with
``--algorithms all``), the per-agent Python loop on A and B with the speed-up, time to accuracy on
paper-example-1, the start-up time of a second run, and with ``--scaling`` the scaling table (one seed, N from 16
to 16 384) idle and beside a busy process.

    python benchmarks/throughput.py [--repeats 3] [--cases A,B,C,D,E] [--algorithms dgtd|all|NAME,...] [--scaling]
                                    [--out benchmarks/results]

Writes throughput.json and throughput.md under --out and prints the table.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))

from per_agent_loop import per_agent_loop  # noqa: E402

from dgtd.algorithms import ALGORITHMS  # noqa: E402
from dgtd.cli.bench import CASES, beside_a_busy_process, markdown, measure, scaling  # noqa: E402
from dgtd.problems import exact  # noqa: E402
from dgtd.run.loop import RunSettings, run  # noqa: E402
from dgtd.scenarios import get_scenario  # noqa: E402


def loop_rows(keys, repeats):
    rows = []
    for key in keys:
        problem, network, algorithm = CASES[key].make()
        d = exact.Moments(problem).d
        seeds = CASES[key].seeds
        T = {"A": 4000, "B": 60}[key]
        secs = [per_agent_loop(problem, network, algorithm, seeds, T, d) for _ in range(repeats)]
        rate = T * seeds * problem.n_agents / float(np.median(secs))
        rows.append(
            {
                "case": key,
                "backend": "per-agent loop",
                "N": problem.n_agents,
                "q": problem.n_features,
                "seeds": seeds,
                "iterations": T,
                "seconds": secs,
                "agent_steps_per_s": rate,
            }
        )
        print(f"{key} per-agent loop {rate:14,.0f} agent-steps/s")
    return rows


def time_to_accuracy(target=0.05, seeds=4):
    """Wall seconds (numba, after compilation) until every agent's averaged iterate is within ``target`` of w*."""
    sc = get_scenario("paper-example-1")
    settings = RunSettings(iterations=sc.iterations, seeds=seeds, checkpoints=400, backend="numba")
    run(sc.problem, sc.network, sc.algorithm, sc.sampling, RunSettings(iterations=100, seeds=seeds, backend="numba"))
    t = time.perf_counter()
    res = run(sc.problem, sc.network, sc.algorithm, sc.sampling, settings)
    secs = time.perf_counter() - t
    ok = np.all(res.metrics["error_avg"] < target, axis=1)
    # the first checkpoint from which the worst seed stays below target
    first = next((c for c in range(len(ok)) if ok[c:].all()), None)
    step = int(res.steps[first]) if first is not None else None
    return {
        "target": target,
        "seeds": seeds,
        "iterations_needed": step,
        "agent_steps_needed": None if step is None else step * sc.problem.n_agents * seeds,
        "seconds_full_run": secs,
        "seconds_to_target": None if step is None else secs * step / sc.iterations,
    }


def startup_seconds():
    """Wall time of `dgtd run paper-example-1 -T 1` in a fresh process (compiled kernels come from the cache)."""
    cmd = [
        sys.executable,
        "-m",
        "dgtd.cli",
        "run",
        "paper-example-1",
        "-T",
        "1",
        "--no-progress",
        "--no-plots",
        "--out",
        "/tmp/dgtd-startup",
    ]
    subprocess.run(cmd, check=True, capture_output=True)
    times = []
    for _ in range(3):
        t = time.perf_counter()
        subprocess.run(cmd, check=True, capture_output=True)
        times.append(time.perf_counter() - t)
    return float(np.median(times))


FIRST_ITERATION = """
import os, sys, time
def since_process_start():
    ticks = os.sysconf("SC_CLK_TCK")
    start = int(open("/proc/self/stat").read().rsplit(")", 1)[1].split()[19]) / ticks
    return float(open("/proc/uptime").read().split()[0]) - start
import dgtd.run.layout as layout
kernel_of = layout.kernel_for
def first_call_reports(backend, algorithm, channel=None):
    kernel = kernel_of(backend, algorithm, channel)
    def wrapped(*args, **kw):
        out = kernel(*args, **kw)
        if not getattr(wrapped, "done", False):  # the first block's compiled code has loaded and run
            wrapped.done = True
            print("FIRST_ITERATION", since_process_start(), flush=True)
        return out
    wrapped.draws_samples = getattr(kernel, "draws_samples", False)
    return wrapped
layout.kernel_for = first_call_reports
from dgtd.cli import main
main(["run", "paper-example-1", "-T", "1", "--no-progress", "--no-plots", "--out", "/tmp/dgtd-startup"])
"""


def first_iteration_seconds(repeats: int = 5, env: dict | None = None) -> list[float]:
    """Seconds from the start of a fresh `dgtd run paper-example-1` process to the end of its first block of
    iterations, loading of the cached compiled kernels included (Linux: the process start time comes from
    /proc), after one run that fills the compilation cache; ``env``: the processes' environment."""
    cmd = [sys.executable, "-c", FIRST_ITERATION]
    subprocess.run(cmd, check=True, capture_output=True, env=env)
    out = []
    for _ in range(repeats):
        text = subprocess.run(cmd, check=True, capture_output=True, text=True, env=env).stdout
        out.append(float(next(line.split()[1] for line in text.splitlines() if line.startswith("FIRST_ITERATION"))))
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--cases", default="A,B,C,D,E")
    ap.add_argument("--algorithms", default="dgtd")
    ap.add_argument("--scaling", action="store_true")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results"))
    args = ap.parse_args()
    keys = args.cases.split(",")
    names = tuple(ALGORITHMS) if args.algorithms == "all" else tuple(args.algorithms.split(","))
    report = measure(keys, repeats=args.repeats, algorithms=names)
    if args.scaling:
        report["scaling"] = {
            "idle": scaling(repeats=args.repeats),
            "busy": beside_a_busy_process(lambda: scaling(repeats=args.repeats)),
        }
    loops = loop_rows([k for k in keys if k in ("A", "B")], args.repeats)
    speedups = {}
    for lr in loops:
        fast = next(
            r
            for r in report["rows"]
            if r["case"] == lr["case"] and r["backend"] == "numba" and r.get("algorithm", "dgtd") == "dgtd"
        )
        speedups[lr["case"]] = fast["agent_steps_per_s"] / lr["agent_steps_per_s"]
    report["per_agent_loop"] = loops
    report["speedup_numba_over_loop"] = speedups
    report["time_to_accuracy_paper_example_1"] = time_to_accuracy()
    report["startup_seconds_second_run"] = startup_seconds()
    report["first_iteration_seconds"] = first_iteration_seconds()
    if os.environ.get("PYTHONDONTWRITEBYTECODE"):
        # Python then writes no bytecode cache, so that a fresh checkout compiles dgtd's own modules in every process;
        # a default Python writes it on the first run
        cached = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
        report["first_iteration_seconds_bytecode_cached"] = first_iteration_seconds(env=cached)
    per_step = {
        r["case"]: 1 / r["agent_steps_per_s"]
        for r in report["rows"]
        if r["backend"] == "numba" and r.get("algorithm", "dgtd") == "dgtd"
    }
    if "B" in per_step and "D" in per_step:
        report["cost_ratio_D_over_B"] = per_step["D"] / per_step["B"]
    md = markdown(report, loops)
    md += "\n\n" + "\n".join(
        f"- Speed-up of numba over the per-agent loop on {k}: {v:,.0f}x" for k, v in speedups.items()
    )
    tta = report["time_to_accuracy_paper_example_1"]
    md += (
        f"\n- paper-example-1, {tta['seeds']} seeds: every agent's averaged iterate stays within "
        f"{tta['target']:.0%} of w* from iteration {tta['iterations_needed']:,} on, "
        f"{tta['seconds_to_target']:.2f} s of a {tta['seconds_full_run']:.2f} s run of 10^6 iterations"
    )
    second = report["startup_seconds_second_run"]
    md += f"\n- A second `dgtd run paper-example-1 -T 1` in a fresh process takes {second:.2f} s in all"
    first = report["first_iteration_seconds"]
    md += (
        f"\n- A fresh `dgtd run paper-example-1` has run its first block of iterations {np.median(first):.2f} s"
        f" after the process starts (median of {len(first)}: {', '.join(f'{x:.2f}' for x in first)})"
    )
    if "first_iteration_seconds_bytecode_cached" in report:
        cached = report["first_iteration_seconds_bytecode_cached"]
        md += (
            f"; with Python's bytecode cache written, {np.median(cached):.2f} s (median of {len(cached)}:"
            f" {', '.join(f'{x:.2f}' for x in cached)}; this environment sets PYTHONDONTWRITEBYTECODE, under which"
            f" a fresh checkout compiles dgtd's modules in every process)"
        )
    if "cost_ratio_D_over_B" in report:
        md += f"\n- Cost per agent-step, N = 10 000 (D) over N = 16 (B): {report['cost_ratio_D_over_B']:.2f}x"
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "throughput.json").write_text(json.dumps(report, indent=2))
    (out / "throughput.md").write_text(md + "\n")
    print(md)


if __name__ == "__main__":
    main()
