"""How the MPI runtime scales: regenerates the measured part of docs/distributed.md and its figures.

    python benchmarks/distributed.py [--weak 50000] [--weak-ranks 1,2,4,8] [--agents 100000,1000000] [--ranks 1,2]

Every measurement starts ``mpiexec -n R`` on this machine (loopback only) running DGTD on the garnet task (30 states,
8 features) with N agents on a small-world graph (the keyed chunked Watts-Strogatz graph of `--graph small-world`:
each agent linked to its 6 nearest in a ring, 2 % of the links rewired at random, so that most links stay inside a
rank), each link up with probability 0.9, one seed, for ``--steps`` steps, with compiled ranks (the default; or
``--backend numpy``, the reference's), and reads back from every rank: the loop's seconds and CPU seconds, how the
seconds split (`dgtd.backends.mpi.SECONDS`) between stepping its share (its own agents and ghosts: samples drawn in
the kernel), exchanging the messages of the links that cross ranks (waiting for the others included), setting up and
drawing outside the kernel, and gathering the state at block ends; and its peak memory. One rank (R = 1) is one
process with the compiled kernels: the baseline.

- Weak scaling (``--weak`` agents a rank, ``--weak-ranks``): CPU seconds a step and peak memory a rank as R grows
  (R ranks share this machine's 2 cores, so wall time grows with R and CPU time is the measure).
- Strong scaling (``--agents``, ``--ranks``): agent-steps per second of R ranks against one process.
- The projection to 64 and 1 024 ranks from the measured costs (`projection`).

With ``--asynchronous-agents`` the strong-scaling runs are repeated with ``--asynchronous`` ranks (no rank waits for
another inside a block; `dgtd.backends.mailbox`; the reference's arithmetic). Then the ages of the messages used
(``--ages``): ``dgtd run garnet --asynchronous`` on 2 and 4 ranks, beside one-process runs of the ``--delay D`` model
of docs/links.md whose closed-form age distribution has the same mean (a message sent at step s arrives after d ~
U{0..D} steps and the newest arrived is used, so P(age > a) = prod_{j<=a} (D - j) / (D + 1)), and the synchronous
run; prints their ages and errors and writes docs/distributed-ages.png.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

DOCS = Path(__file__).resolve().parents[1] / "docs"
# NumPy is imported where used, after dgtd: dgtd gives each rank its share of the BLAS threads, which NumPy fixes when
# it loads (imported first, 100 000 agents' setup took 84 s on each of 2 ranks instead of 6 s)
FEATURES, STATES = 8, 30
HOP = 5e-6  # seconds of one small MPI message between cluster machines (assumed, for the projection)
BANDWIDTH = 10e9  # bytes a second a rank receives over a cluster's network (assumed, for the projection)
CHECKPOINTS = 10  # metrics measured (and combined over the ranks) about every tenth of the run, as a run's are


def worker(n_agents: int, steps: int, asynchronous: int = 0, compiled: int = 1) -> None:
    """One measurement, on every rank of the mpiexec job this runs in; rank 0 prints one JSON line."""
    from dgtd.algorithms import make_algorithm
    from dgtd.backends import mpi
    from dgtd.graphs.random import random_edges
    from dgtd.problems import tasks
    from dgtd.run.loop import RunSettings, Sampling, run

    problem = tasks.garnet(STATES, 3, n_agents, FEATURES, seed=0)
    network = random_edges(small_world(n_agents), 0.9)
    algorithm = make_algorithm("dgtd", alpha0=1.0, beta=1000.0)
    t0 = time.perf_counter()
    backend = "numba" if compiled and not asynchronous else "numpy"
    settings = RunSettings(
        iterations=steps,
        seeds=1,
        checkpoints=CHECKPOINTS,
        backend=backend,
        block_size=steps,
        asynchronous=bool(asynchronous),
    )
    result = run(problem, network, algorithm, Sampling(), settings)
    total = time.perf_counter() - t0
    mine = {
        **mpi.SECONDS,
        "loop": result.info["loop_seconds"],  # the steps and the metrics at checkpoints
        "cpu": result.info["loop_cpu_seconds"],
        "setup": total - result.info["loop_seconds"] - mpi.SECONDS["gather"],
        "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }
    every = mpi.world().gather(mine, root=0) if mpi.world() is not None else [mine]
    if mpi.rank() == 0:
        mode = "asynchronous" if asynchronous else "synchronous"
        print(
            json.dumps(
                {"agents": n_agents, "ranks": mpi.size(), "steps": steps, "mode": mode, "backend": backend}
                | {"per_rank": every}
            )
        )


def small_world(n: int, k: int = 6, rewired: float = 0.02, seed: int = 0):
    """The keyed chunked Watts-Strogatz graph (`dgtd.graphs.chunked`, as `--graph small-world` makes it): agent i
    linked to its k / 2 next around a ring, a fraction ``rewired`` of the links moved to an agent drawn at random."""
    from dgtd.graphs import chunked
    from dgtd.graphs.topologies import from_edges

    graph = chunked.ChunkedGraph("small-world", n, k, rewire=rewired, seed=seed)
    return from_edges(n, chunked.whole(graph).edges, "small world")


MPIEXEC = Path(sys.executable).parent / "mpiexec"


def measure(ranks: int, n_agents: int, steps: int, asynchronous: bool = False, compiled: bool = True) -> dict:
    cmd = [str(MPIEXEC), "-n", str(ranks), sys.executable, __file__, "--worker", str(n_agents), str(steps)]
    cmd += [str(int(asynchronous)), str(int(compiled))]
    env = dict(os.environ, MPIEXEC_TIMEOUT="3000")
    done = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=3600)
    if done.returncode != 0:
        raise RuntimeError(f"mpiexec -n {ranks}, {n_agents} agents failed:\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def row(m: dict) -> dict:
    ranks = m["per_rank"]
    loop = max(r["loop"] for r in ranks)
    share = lambda key: max(r[key] for r in ranks) / loop  # noqa: E731
    return dict(
        agents=m["agents"],
        ranks=m["ranks"],
        mode=m["mode"],
        backend=m["backend"],
        steps=m["steps"],
        rounds=m["steps"] / loop,
        agent_steps=m["steps"] * m["agents"] / loop,
        cpu_per_step=max(r["cpu"] for r in ranks) / m["steps"],
        own=share("own"),
        draws=share("draws"),
        exchange=share("exchange"),
        reduce=share("reduce"),
        own_seconds=max(r["own"] for r in ranks),
        exchange_seconds=max(r["exchange"] for r in ranks),
        reduce_seconds=max(r["reduce"] for r in ranks),
        gather_seconds=max(r["gather"] for r in ranks),
        mb_per_rank=max(r["rss_mb"] for r in ranks),
        setup=max(r["setup"] for r in ranks),
    )


def table(rows: list[dict]) -> str:
    lines = [
        "| agents | ranks | kernels | mode | rounds/s | agent-steps/s | CPU s a step (a rank) | stepping its share | "
        "set-up and draws | exchange | metrics combined | peak memory a rank | setup (s) |",
        "| ---: | ---: | :--- | :--- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in rows:
        if r["ranks"] == 1:  # one process: the kernels alone, nothing split or exchanged
            r = {**r, "own": float("nan"), "draws": float("nan"), "exchange": float("nan"), "reduce": float("nan")}
        pct = lambda x, digits=0: "-" if x != x else f"{x:.{digits}%}"  # noqa: E731  (NaN: one process)
        kernels = "compiled" if r["backend"] == "numba" else "NumPy"
        lines.append(
            f"| {r['agents']:,} | {r['ranks']} | {kernels} | {r['mode'][:5]} | {r['rounds']:,.1f} | "
            f"{r['agent_steps'] / 1e6:.3f} M | {r['cpu_per_step'] * 1e3:.1f} ms | "
            f"{pct(r['own'])} | {pct(r['draws'])} | {pct(r['exchange'])} | {pct(r['reduce'], 1)} | "
            f"{r['mb_per_rank']:,.0f} MB | {r['setup']:.1f} |"
        )
    return "\n".join(lines)


def tree_seconds(n_agents: int, ranks: int) -> tuple[float, int]:
    """(seconds, bytes) of one of the consensus metric's sums over the fixed tree of agents on ``ranks`` ranks of
    ``n_agents`` (`dgtd.backends.mpi.Ranks.tree_sum`), measured in this process: the pieces of every rank's block
    combined (`dgtd.problems.exact.tree_total`, which every rank does), and the bytes every rank receives."""
    import numpy as np

    from dgtd.problems.exact import joined, tree_pieces, tree_total

    bounds = np.linspace(0, n_agents, ranks + 1).astype(np.int64)
    x = np.ones((1, int(np.diff(bounds).max()), FEATURES))
    pieces = joined([tree_pieces(x[:, : hi - lo], int(lo)) for lo, hi in zip(bounds[:-1], bounds[1:])])
    t0 = time.perf_counter()
    for _ in range(5):
        tree_total(pieces, n_agents, (1, FEATURES))
    return (time.perf_counter() - t0) / 5, sum(a.nbytes for a in pieces)


def projection(rows: list[dict], agents=(10**6, 10**8), ranks=(64, 1024)) -> str:
    """Seconds a step on R cluster ranks of N agents, from the 2-rank compiled measurement of the most agents: each rank
    steps N / R agents at the measured cost per agent-step and exchanges a boundary that does not grow with N / R (the
    measured exchange a step, waiting included); at checkpoints it measures its own agents' errors and the ranks
    combine them (the measured seconds per own agent and checkpoint, `dgtd.backends.mpi.Ranks`), and the consensus
    metric's two sums over the fixed tree of agents each gather every rank's pieces (4 allgathers of log2 R rounds at
    ``HOP`` seconds a message, a cluster network's latency, assumed: one machine's ranks cannot measure it; their
    bytes at ``BANDWIDTH``, assumed) and combine them on every rank (`tree_seconds`, measured)."""
    import math

    two = [r for r in rows if r["ranks"] == 2 and r["backend"] == "numba" and r["mode"] == "synchronous"]
    if not two:
        return ""
    m = max(two, key=lambda r: r["agents"])
    per_agent_step = m["own_seconds"] / (m["steps"] * m["agents"] / 2)
    exchange = m["exchange_seconds"] / m["steps"]
    every = m["steps"] / CHECKPOINTS  # steps between checkpoints
    per_agent_checkpoint = m["reduce_seconds"] / CHECKPOINTS / (m["agents"] / 2)
    lines = [
        f"From {m['agents']:,} agents on 2 ranks: {per_agent_step * 1e9:.0f} ns an agent-step, {exchange * 1e3:.2f} ms "
        f"of exchange a step, {per_agent_checkpoint * 1e9:.0f} ns an own agent for the metrics at a checkpoint, "
        f"every {every:.0f} steps; {HOP * 1e6:.0f} us a message from rank to rank and {BANDWIDTH / 1e9:.0f} GB/s "
        "(assumed); the tree's combine measured here.",
        "",
        "| agents | ranks | stepping (ms a step) | exchange | tree sums (ms a checkpoint) | metrics, per step | "
        "rounds/s |",
        "| ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for n in agents:
        for R in ranks:
            step = n / R * per_agent_step
            combine, nbytes = tree_seconds(n, R)
            tree = 2 * (4 * math.ceil(math.log2(R)) * HOP + nbytes / BANDWIDTH + combine)
            metrics = (n / R * per_agent_checkpoint + tree) / every
            total = step + exchange + metrics
            lines.append(
                f"| {n:,} | {R:,} | {step * 1e3:.2f} | {exchange * 1e3:.2f} | {tree * 1e3:.2f} | {metrics * 1e3:.2f} | "
                f"{1 / total:,.1f} |"
            )
    return "\n".join(lines)


def figure(weak: list[dict], strong: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(12, 3.4))
    if weak:
        pts = sorted(weak, key=lambda r: r["ranks"])
        R = [r["ranks"] for r in pts]
        axes[0].plot(R, [r["cpu_per_step"] * 1e3 for r in pts], "o-")
        axes[1].plot(R, [r["mb_per_rank"] for r in pts], "o-")
        for ax, what in ((axes[0], "CPU ms a step, a rank"), (axes[1], "peak memory a rank (MB)")):
            ax.set_xlabel(f"ranks ({pts[0]['agents'] // pts[0]['ranks']:,} agents each, on 2 cores)")
            ax.set_ylabel(what)
            ax.set_xticks(R)
            ax.set_ylim(bottom=0)
    for n in sorted({r["agents"] for r in strong}):
        pts = sorted((r for r in strong if r["agents"] == n and r["mode"] == "synchronous"), key=lambda r: r["ranks"])
        axes[2].plot([r["ranks"] for r in pts], [r["agent_steps"] for r in pts], "o-", label=f"{n:,} agents")
    axes[2].set_xlabel("ranks (on 2 cores)")
    axes[2].set_ylabel("agent-steps per second")
    axes[2].set_xticks(sorted({r["ranks"] for r in strong}) or [1])
    axes[2].set_ylim(bottom=0)
    axes[2].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def delay_model_ages(D: int, n: int):
    """P(age = a), a = 0 .. n - 1, of the message used under the --delay D model (module docstring)."""
    import numpy as np

    beyond = np.cumprod([max(D - j, 0) / (D + 1) for j in range(n)])  # P(age > a)
    return np.concatenate([[1.0], beyond[:-1]]) - beyond


def dgtd_run(out: Path, *args, ranks: int = 0) -> dict:
    """summary.json and the error_avg curve of `dgtd run garnet ARGS` (under ``mpiexec -n ranks`` when ranks)."""
    cmd = [sys.executable, "-m", "dgtd.cli", "run", "garnet", "-T", str(AGES_STEPS), "--seeds", str(AGES_SEEDS)]
    cmd += ["--no-plots", "--no-progress"]
    cmd = ([str(MPIEXEC), "-n", str(ranks)] if ranks else []) + cmd + [*map(str, args), "--out", str(out)]
    done = subprocess.run(cmd, capture_output=True, text=True, env=dict(os.environ, MPIEXEC_TIMEOUT="3000"))
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{done.stderr[-2000:]}")
    summary = json.loads((out / "summary.json").read_text())
    worst: dict = {}  # the worst seed's at each step
    with open(out / "metrics.csv") as f:
        for r in csv.DictReader(f):
            if r["metric"] == "error_avg":
                worst[int(r["step"])] = max(worst.get(int(r["step"]), 0.0), float(r["value"]))
    curve = sorted(worst.items())
    return {"summary": summary, "curve": curve}


AGES_STEPS, AGES_SEEDS = 20_000, 4


def ages_study(work: Path) -> None:
    """Asynchronous ranks' message ages beside the --delay model's, and what they do to DGTD's error (garnet)."""
    import numpy as np

    runs = {"one process, synchronous": dgtd_run(work / "sync", "--backend", "numpy")}
    lines = ["| run | mean age | median | 95th percentile | largest | mean transit | error_avg at the end |"]
    lines.append("| :--- | ---: | ---: | ---: | ---: | ---: | ---: |")
    matched = {}
    for ranks in (2, 4):
        name = f"{ranks} ranks, asynchronous"
        runs[name] = dgtd_run(work / f"async{ranks}", "--asynchronous", ranks=ranks)
        mean = runs[name]["summary"]["message_ages"]["mean"]
        D = min(range(1, 200), key=lambda D: abs(delay_model_ages(D, 400) @ np.arange(400) - mean))
        matched[name] = D
        runs[f"one process, --delay {D}"] = dgtd_run(work / f"delay{D}", "--delay", D, "--backend", "numpy")
    for name, r in runs.items():
        ages = r["summary"].get("message_ages")
        error = f"{r['summary']['max_error_avg']:.2%}"
        if ages is None:
            D = int(r["summary"]["config"]["delay"] or 0)
            p = delay_model_ages(D, 400)
            cdf = np.cumsum(p)
            model = [p @ np.arange(400), np.searchsorted(cdf, 0.5), np.searchsorted(cdf, 0.95), D]
            name += " (model)" if D else ""
            lines.append(f"| {name} | {model[0]:.2f} | {model[1]} | {model[2]} | {model[3]} | - | {error} |")
        else:
            transit = f"{ages['transit_seconds_mean'] * 1e6:.0f} us"
            lines.append(
                f"| {name} | {ages['mean']:.2f} | {ages['median']} | {ages['p95']} | {ages['max']} | {transit} | "
                f"{error} |"
            )
    print("\n".join(lines))
    ages_figure(runs, matched, DOCS / "distributed-ages.png")
    print(f"wrote {DOCS / 'distributed-ages.png'}")


def ages_figure(runs: dict, matched: dict, path: Path) -> None:
    import matplotlib
    import numpy as np

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    colour, right = {}, 0
    for i, (name, D) in enumerate(matched.items()):
        colour[name] = colour[f"one process, --delay {D}"] = f"C{i}"
        steps = runs[name]["summary"]["message_ages"]["steps"]
        ages = np.array([int(a) for a in steps])
        counts = np.array(list(steps.values()), dtype=float)
        top = int(np.percentile(np.repeat(ages, counts.astype(int)), 99.5)) + 2
        axes[0].bar(ages + 0.2 * (2 * i - 1), counts / counts.sum(), width=0.4, color=f"C{i}", label=name)
        axes[0].plot(np.arange(top), delay_model_ages(D, top), "o--", color=f"C{i}", ms=3, label=f"--delay {D} model")
        right = max(right, top)
    axes[0].set_xlim(-0.8, right)
    axes[0].set_xlabel("age of the message used (steps)")
    axes[0].set_ylabel("share of messages used")
    axes[0].legend(fontsize=7)
    for name, r in runs.items():
        steps, error = zip(*r["curve"])
        style = "-" if "asynchronous" in name else ":" if "delay" in name else "-"
        axes[1].plot(steps, error, style, label=name, color=colour.get(name, "k"))
    axes[1].set_xscale("log")
    axes[1].set_yscale("log")
    axes[1].set_xlabel("step")
    axes[1].set_ylabel("error_avg (worst agent and seed)")
    axes[1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--weak", type=int, default=50_000, help="agents a rank for the weak scaling (0: none)")
    parser.add_argument("--weak-ranks", default="1,2,4,8")
    parser.add_argument("--ranks", default="1,2")
    parser.add_argument("--agents", default="100000,1000000")
    parser.add_argument("--asynchronous-agents", default="")
    parser.add_argument("--backend", default="numba", choices=("numba", "numpy"))
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--no-scaling", action="store_true", help="only the ages study")
    parser.add_argument("--no-ages", action="store_true", help="only the scaling tables")
    parser.add_argument("--worker", nargs=4, type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker(*args.worker)
        return
    compiled = args.backend == "numba"
    if not args.no_scaling:
        weak, strong = [], []
        for ranks in map(int, args.weak_ranks.split(",")) if args.weak else ():
            weak.append(row(measure(ranks, args.weak * ranks, args.steps, compiled=compiled)))
            print(table(weak[-1:]).splitlines()[-1], flush=True)
        also = set(map(int, args.asynchronous_agents.split(","))) if args.asynchronous_agents else set()
        for n in map(int, args.agents.split(",")):
            for ranks in map(int, args.ranks.split(",")):
                for asynchronous in (False, True) if n in also and ranks > 1 else (False,):
                    strong.append(row(measure(ranks, n, args.steps, asynchronous, compiled)))
                    print(table(strong[-1:]).splitlines()[-1], flush=True)
        print("Weak scaling:\n" + table(weak) + "\n\nStrong scaling:\n" + table(strong))
        print("\nProjection:\n" + projection(strong))
        figure(weak, strong, DOCS / "distributed.png")
        print(f"wrote {DOCS / 'distributed.png'}")
    if not args.no_ages:
        with tempfile.TemporaryDirectory() as work:
            ages_study(Path(work))


if __name__ == "__main__":
    main()
