"""Throughput measurements: agent-steps per second of whole runs, of every algorithm, the machine's copy bandwidth,
and what an agent-step costs in bytes and flops; and the scaling table (one seed, N from 16 to 16 384), idle and
beside a busy process. Used by `dgtd bench` and benchmarks/throughput.py.

One agent-step is one agent's full update (one learner's, for a centralised method), sampling included: a run of T
iterations with B seeds and N agents is T * B * N agent-steps. The bytes and flops are DGTD's.
"""

from __future__ import annotations

import platform
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from dgtd.algorithms import make_algorithm
from dgtd.algorithms.dgtd import DGTD
from dgtd.graphs import topologies
from dgtd.graphs.random import RandomEdges, random_edges
from dgtd.problems.generators import random_problem
from dgtd.problems.model import Problem
from dgtd.run.loop import RunSettings, run
from dgtd.scenarios import get_scenario
from dgtd.sources.model import Sampling


@dataclass(frozen=True)
class BenchCase:
    """A benchmark configuration: the problem, the network, how many seeds, and iterations per backend."""

    key: str
    description: str
    make: Callable[[], tuple[Problem, RandomEdges, DGTD]]
    seeds: int
    iterations: dict


def _connected_geometric(n: int, mean_degree: float, seed: int):
    import networkx as nx

    radius = np.sqrt(mean_degree / (np.pi * n))
    for k in range(100):
        G = nx.random_geometric_graph(n, radius, seed=seed + k)
        if nx.is_connected(G):
            return topologies.from_networkx(G)
        radius *= 1.05
    raise RuntimeError("no connected geometric graph found")


def _sparse_random(n: int, mean_degree: int, rng: np.random.Generator):
    """A ring (for connectivity) plus (mean_degree / 2 - 1) * n random chords: mean degree about mean_degree."""
    ring = [(i, (i + 1) % n) for i in range(n)]
    m = (mean_degree // 2 - 1) * n
    u, v = rng.integers(n, size=(2, m))
    keep = u != v
    return topologies.from_edges(n, ring + list(zip(u[keep], v[keep])), f"sparse-random-deg{mean_degree}")


def _case_a():
    sc = get_scenario("paper-example-1")
    return sc.problem, sc.network, sc.algorithm


def _case_b():
    rng = np.random.default_rng(1)
    return (
        random_problem(128, 16, 64, rng),
        random_edges(topologies.ring_with_chords(16, 4), 0.5),
        DGTD(alpha0=0.5, beta=10),
    )


def _case_c():
    rng = np.random.default_rng(2)
    return (
        random_problem(128, 1000, 64, rng),
        random_edges(_connected_geometric(1000, 10, 2), 0.9),
        DGTD(alpha0=0.5, beta=10),
    )


def _case_d():
    rng = np.random.default_rng(3)
    return (
        random_problem(128, 10_000, 64, rng),
        random_edges(_sparse_random(10_000, 6, rng), 0.9),
        DGTD(alpha0=0.5, beta=10),
    )


def _case_e():
    rng = np.random.default_rng(4)
    return random_problem(400, 3, 400, rng), random_edges(topologies.complete(3), 0.5), DGTD(alpha0=0.5, beta=10)


CASES = {
    "A": BenchCase("A", "paper-example-1 (N=5, q=2), 1 seed", _case_a, 1, {"numba": 1_000_000, "numpy": 20_000}),
    "B": BenchCase(
        "B",
        "N=16, q=64, random 128-state problem, ring with chords, p=0.5, 32 seeds",
        _case_b,
        32,
        {"numba": 20_000, "numpy": 1_000},
    ),
    "C": BenchCase(
        "C",
        "N=1000, q=64, random geometric graph (mean degree ~10), p=0.9, 1 seed",
        _case_c,
        1,
        {"numba": 5_000, "numpy": 200},
    ),
    "D": BenchCase(
        "D",
        "N=10000, q=64, sparse random graph (mean degree 6), p=0.9, 1 seed",
        _case_d,
        1,
        {"numba": 500, "numpy": 20},
    ),
    "E": BenchCase(
        "E", "tabular, 400 states, N=3, complete graph, p=0.5, 1 seed", _case_e, 1, {"numba": 100_000, "numpy": 5_000}
    ),
}


def bench_algorithm(name: str, case_algorithm: DGTD):
    """The algorithm ``name`` as a bench case runs it: DGTD with the case's steps; another at a step small enough
    that no run diverges on these cases (a diverged run stops early, and would look fast)."""
    return case_algorithm if name == case_algorithm.name else make_algorithm(name, alpha0=0.05, beta=10.0)


def time_run(
    problem, network, algorithm, seeds: int, iterations: int, backend: str, repeats: int, channel=None
) -> list[float]:
    """Wall seconds of `run`'s iterations (sampling, updates, the final metric checkpoint), after a warm-up run;
    the one-off setup (exact solution, tables) is timed apart by `setup_seconds`. ``channel``: the run's
    (`dgtd.channels`; default the perfect one)."""
    settings = RunSettings(iterations=iterations, seeds=seeds, checkpoints=1, backend=backend)
    run(
        problem,
        network,
        algorithm,
        Sampling(),
        RunSettings(iterations=min(iterations, 50), seeds=seeds, checkpoints=1, backend=backend),
        channel=channel,
    )
    out = []
    for _ in range(repeats):
        result = run(problem, network, algorithm, Sampling(), settings, channel=channel)
        if (result.info["diverged_at"] >= 0).any():
            raise RuntimeError(f"{algorithm.name} diverged on the bench case: its time would not be a full run's")
        out.append(result.info["loop_seconds"])
    return out


def setup_seconds(problem, network, algorithm) -> float:
    """Wall seconds of a run's one-off preparation: checks, exact solution, boxes and sampler tables."""
    from dgtd.run.loop import prepare

    t = time.perf_counter()
    prepare(problem, network, algorithm, Sampling(), RunSettings(iterations=1))
    return time.perf_counter() - t


def copy_bandwidth(n_bytes: int = 400_000_000, repeats: int = 5) -> float:
    """STREAM-style copy, in bytes moved (read + write) per second, best of ``repeats``."""
    a = np.ones(n_bytes // 8)
    b = np.empty_like(a)
    np.copyto(b, a)
    best = min(_timed(lambda: np.copyto(b, a)) for _ in range(repeats))
    return 2 * a.nbytes / best


def _timed(f) -> float:
    t = time.perf_counter()
    f()
    return time.perf_counter() - t


def bytes_per_agent_step(q: int, mean_degree: float) -> dict:
    """Memory traffic of one agent-step of the compiled kernel, float64.

    Compulsory: theta read + write (2q), (v, mu) read + write (4q), the row neighbours read, (w, v + mu), read
    at k and written at k + 1 (4q), the running sum of w read + write (2q): 12 vectors of q. The neighbours' rows
    (2q per up edge) may come from the caches; they are listed apart.
    """
    return {"compulsory": 12 * q * 8, "neighbours": 2 * q * 8 * mean_degree}


def flops_per_agent_step(q: int, mean_degree: float) -> float:
    """Floating-point operations of one agent-step with dense features: 3 dot products (6q), the Laplacian rows
    of (w, v + mu) (2q adds per up neighbour, 4q to finish), and the updates with projection (~26q)."""
    return 6 * q + 2 * q * mean_degree + 4 * q + 26 * q


def _cpuinfo() -> dict:
    """The first processor's fields in /proc/cpuinfo (Linux; empty elsewhere): "model name", "cpu MHz", "flags"."""
    fields: dict = {}
    try:
        for line in open("/proc/cpuinfo"):
            key, _, value = line.partition(":")
            if not key.strip() and fields:  # the blank line after the first processor
                break
            fields.setdefault(key.strip(), value.strip())
    except OSError:
        pass
    return fields


def peak_flops(cores: int) -> tuple[float, str]:
    """Double-precision peak (flops/s) and how it was reckoned: cores x nominal clock x 2 FMA units x vector lanes
    (8 with AVX-512, 4 with AVX2, 2 otherwise) x 2 flops. The clock is the one /proc/cpuinfo reports (2.8 GHz
    where it reports none); a core that runs faster than it reaches a higher peak than the one stated."""
    info = _cpuinfo()
    try:
        ghz = float(info.get("cpu MHz", "")) / 1000
    except ValueError:
        ghz = 2.8
    flags = set(info.get("flags", "").split())
    lanes, isa = (8, "AVX-512") if "avx512f" in flags else ((4, "AVX2") if "avx2" in flags else (2, "SSE2"))
    return cores * ghz * 1e9 * 2 * lanes * 2, f"2 {isa} FMA units per core at {ghz:.2f} GHz"


def machine() -> str:
    import os

    cpu = _cpuinfo().get("model name") or platform.processor() or platform.machine()
    return f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}, {platform.system()}"


def measure(
    keys=("A", "B", "C", "D", "E"), backends=("numba", "numpy"), repeats: int = 3, progress=print, algorithms=("dgtd",)
) -> dict:
    """Agent-steps per second (median of ``repeats``) for each case, algorithm and backend, with bandwidth and flop
    context (DGTD's)."""
    from numba import get_num_threads

    bw = copy_bandwidth()
    peak, peak_basis = peak_flops(get_num_threads())
    rows = []
    for key in keys:
        case = CASES[key]
        problem, network, dgtd = case.make()
        N, q = problem.n_agents, problem.n_features
        mean_deg = 2 * network.n_edges * float(network.p.mean()) / N
        for name in algorithms:
            algorithm = bench_algorithm(name, dgtd)
            for backend in backends:
                T = case.iterations[backend]
                secs = time_run(problem, network, algorithm, case.seeds, T, backend, repeats)
                med = float(np.median(secs))
                rate = T * case.seeds * N / med
                row = {
                    "case": key,
                    "description": case.description,
                    "algorithm": name,
                    "backend": backend,
                    "N": N,
                    "q": q,
                    "setup_seconds": setup_seconds(problem, network, algorithm),
                    "seeds": case.seeds,
                    "iterations": T,
                    "seconds": secs,
                    "agent_steps_per_s": rate,
                    "mean_up_degree": mean_deg,
                }
                if name == "dgtd":
                    by, fl = bytes_per_agent_step(q, mean_deg), flops_per_agent_step(q, mean_deg)
                    row |= {
                        "bytes_per_agent_step": by,
                        "flops_per_agent_step": fl,
                        "bandwidth_bound_agent_steps_per_s": bw / by["compulsory"],
                        "fraction_of_bandwidth_bound": rate / (bw / by["compulsory"]),
                        "fraction_of_peak_flops": rate * fl / peak,
                    }
                rows.append(row)
                progress(
                    f"{key} {name:14s} {backend:6s} {rate:14,.0f} agent-steps/s  (median of {repeats}: {med:.3f} s)"
                )
    return {
        "machine": machine(),
        "threads": get_num_threads(),
        "copy_bandwidth_bytes_per_s": bw,
        "peak_flops": peak,
        "peak_basis": peak_basis,
        "date": time.strftime("%Y-%m-%d"),
        "rows": rows,
    }


SCALING_AGENTS = (16, 64, 256, 1024, 4096, 16384)
SCALING_AGENT_STEPS = 4_000_000  # per run: T = this / N iterations


def scaling_case(N: int):
    """One seed of N agents, q = 64, a random 128-state problem, a sparse random graph (mean degree 6), p = 0.9."""
    rng = np.random.default_rng(5)
    return random_problem(128, N, 64, rng), random_edges(_sparse_random(N, 6, rng), 0.9), DGTD(alpha0=0.5, beta=10)


def scaling(agents=SCALING_AGENTS, repeats: int = 3, progress=print, algorithm: str = "dgtd") -> list[dict]:
    """Agent-steps per second of one seed against N (the compiled backend, its layouts chosen as a run chooses)."""
    rows = []
    for N in agents:
        problem, network, dgtd = scaling_case(N)
        T = max(20, SCALING_AGENT_STEPS // N)
        secs = time_run(problem, network, bench_algorithm(algorithm, dgtd), 1, T, "numba", repeats)
        rate = T * N / float(np.median(secs))
        rows.append({"N": N, "iterations": T, "seconds": secs, "agent_steps_per_s": rate})
        progress(f"N = {N:6d} {algorithm:14s} {rate:14,.0f} agent-steps/s")
    return rows


BUSY = "import time\nend = time.monotonic() + {seconds}\nwhile time.monotonic() < end:\n    pass\n"


def beside_a_busy_process(measure_fn, seconds: float = 3600.0):
    """``measure_fn()`` while another process keeps one core busy (a Python loop that stops by itself after
    ``seconds``, and is stopped when the measurement ends)."""
    import subprocess
    import sys

    busy = subprocess.Popen([sys.executable, "-c", BUSY.format(seconds=seconds)])
    try:
        time.sleep(0.5)  # running before the first measurement
        return measure_fn()
    finally:
        busy.kill()
        busy.wait(timeout=10)


def markdown(report: dict, extra_rows: list | None = None) -> str:
    """The report as Markdown tables: the cases (DGTD's with its bytes and flops), and the scaling table if any."""
    lines = [
        f"Measured {report['date']} on {report['machine']} ({report['threads']} threads); "
        f"STREAM-style copy bandwidth {report['copy_bandwidth_bytes_per_s'] / 1e9:.1f} GB/s (read + write); "
        f"double-precision peak {report['peak_flops'] / 1e9:.0f} GFLOP/s ({report['peak_basis']}).",
        "",
        "| case | algorithm | backend | N | q | seeds | agent-steps/s | bytes/agent-step (compulsory + neighbours) | "
        "bandwidth bound | of bound | flops/agent-step | of peak |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in report["rows"] + (extra_rows or []):
        by = r.get("bytes_per_agent_step")
        lines.append(
            f"| {r['case']} | {r.get('algorithm', 'dgtd')} | {r['backend']} | {r['N']} | {r['q']} | {r['seeds']} | "
            f"{r['agent_steps_per_s']:,.0f} | "
            + (
                f"{by['compulsory']:,} + {by['neighbours']:,.0f} | {r['bandwidth_bound_agent_steps_per_s']:,.0f} | "
                f"{r['fraction_of_bandwidth_bound']:.0%} | {r['flops_per_agent_step']:,.0f} | "
                f"{r['fraction_of_peak_flops']:.1%} |"
                if by
                else "| | | | |"
            )
        )
    if report.get("scaling"):
        lines += [
            "",
            "Scaling, one seed (`scaling_case`): agent-steps per second idle and beside a process that keeps "
            "one core busy.",
            "",
            "| N | idle | beside a busy process | busy / idle |",
            "| --- | --- | --- | --- |",
        ]
        for idle, busy in zip(report["scaling"]["idle"], report["scaling"].get("busy") or [None] * 99):
            lines.append(
                f"| {idle['N']} | {idle['agent_steps_per_s']:,.0f} | "
                + (
                    f"{busy['agent_steps_per_s']:,.0f} | {busy['agent_steps_per_s'] / idle['agent_steps_per_s']:.2f} |"
                    if busy
                    else "| |"
                )
            )
    return "\n".join(lines)
