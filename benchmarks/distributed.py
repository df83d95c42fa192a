"""How the MPI runtime scales: regenerates the measured part of docs/distributed.md and its figure.

    python benchmarks/distributed.py [--ranks 1,2,4] [--agents 1000,10000,100000] [--steps 200]

For each number of agents N and of ranks R it starts ``mpiexec -n R`` on this machine (loopback only) running DGTD on
the garnet task (30 states, 8 features) with N agents on a small-world graph (networkx's connected Watts-Strogatz
graph: each agent linked to its 6 nearest in a ring, 2 % of the links rewired at random, so that most links stay
inside a rank and the graph is well connected), each link up with probability 0.9, one seed, for ``--steps`` steps,
and reads back from every rank: the loop's seconds, and how they split (`dgtd.backends.mpi.SECONDS`) between updating
its own agents, drawing what every rank draws (the samples and the channel's events of all agents), exchanging the
messages of the links that cross ranks (waiting for the others included) and gathering the state at block ends; and
its peak memory. Prints a Markdown table and writes docs/distributed.png.

With ``--asynchronous-agents`` (default 1000,10000) the same runs are repeated with ``--asynchronous`` ranks (no rank
waits for another inside a block; `dgtd.backends.mailbox`), interleaved with the synchronous ones. Then the ages of
the messages used (``--ages``): ``dgtd run garnet --asynchronous`` on 2 and 4 ranks, beside one-process runs of the
``--delay D`` model of docs/links.md whose closed-form age distribution has the same mean (a message sent at step s
arrives after d ~ U{0..D} steps and the newest arrived is used, so P(age > a) = prod_{j<=a} (D - j) / (D + 1)), and
the synchronous run; prints their ages and errors and writes docs/distributed-ages.png.
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


def worker(n_agents: int, steps: int, asynchronous: int = 0) -> None:
    """One measurement, on every rank of the mpiexec job this runs in; rank 0 prints one JSON line."""
    import networkx as nx

    from dgtd.algorithms import make_algorithm
    from dgtd.backends import mpi
    from dgtd.graphs.random import random_edges
    from dgtd.graphs.topologies import from_networkx
    from dgtd.problems import tasks
    from dgtd.run.loop import RunSettings, Sampling, run

    problem = tasks.garnet(STATES, 3, n_agents, FEATURES, seed=0)
    network = random_edges(from_networkx(nx.connected_watts_strogatz_graph(n_agents, 6, 0.02, seed=0)), 0.9)
    algorithm = make_algorithm("dgtd", alpha0=1.0, beta=1000.0)
    t0 = time.perf_counter()
    settings = RunSettings(
        iterations=steps, seeds=1, checkpoints=1, backend="numpy", block_size=steps, asynchronous=bool(asynchronous)
    )
    result = run(problem, network, algorithm, Sampling(), settings)
    total = time.perf_counter() - t0
    mine = {
        **mpi.SECONDS,
        "loop": result.info["loop_seconds"],
        "setup": total - result.info["loop_seconds"],
        "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }
    every = mpi.world().gather(mine, root=0) if mpi.world() is not None else [mine]
    if mpi.rank() == 0:
        mode = "asynchronous" if asynchronous else "synchronous"
        print(json.dumps({"agents": n_agents, "ranks": mpi.size(), "steps": steps, "mode": mode, "per_rank": every}))


MPIEXEC = Path(sys.executable).parent / "mpiexec"


def measure(ranks: int, n_agents: int, steps: int, asynchronous: bool = False) -> dict:
    cmd = [str(MPIEXEC), "-n", str(ranks), sys.executable, __file__, "--worker", str(n_agents), str(steps)]
    cmd.append(str(int(asynchronous)))
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
        rounds=m["steps"] / loop,
        agent_steps=m["steps"] * m["agents"] / loop,
        own=share("own"),
        replicated=share("replicated") + (loop - max(r["own"] + r["replicated"] + r["exchange"] for r in ranks)) / loop,
        exchange=share("exchange"),
        gather=share("gather"),
        kb_per_agent=max(r["rss_mb"] for r in ranks) * 1024 / m["agents"],
        setup=max(r["setup"] for r in ranks),
    )


def table(rows: list[dict]) -> str:
    lines = [
        "| agents | ranks | mode | rounds/s | agent-steps/s | own agents | drawn on every rank | exchange | gather | "
        "peak memory a rank, per agent | setup (s) |",
        "| ---: | ---: | :--- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in rows:
        if r["ranks"] == 1:  # one process: the plain reference kernel, nothing split or exchanged
            r = {**r, "own": float("nan"), "replicated": float("nan"), "exchange": float("nan"), "gather": float("nan")}
        pct = lambda x, digits=0: "-" if x != x else f"{x:.{digits}%}"  # noqa: E731  (NaN: one process)
        lines.append(
            f"| {r['agents']:,} | {r['ranks']} | {r['mode'][:5]} | {r['rounds']:,.1f} | "
            f"{r['agent_steps'] / 1e6:.3f} M | "
            f"{pct(r['own'])} | {pct(r['replicated'])} | {pct(r['exchange'])} | {pct(r['gather'], 1)} | "
            f"{r['kb_per_agent']:.1f} KB | {r['setup']:.1f} |"
        )
    return "\n".join(lines)


def figure(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9, 3.4))
    for n in sorted({r["agents"] for r in rows}):
        pts = sorted((r for r in rows if r["agents"] == n and r["mode"] == "synchronous"), key=lambda r: r["ranks"])
        axes[0].plot([r["ranks"] for r in pts], [r["agent_steps"] for r in pts], "o-", label=f"{n:,} agents")
        axes[1].plot([r["ranks"] for r in pts], [r["exchange"] for r in pts], "o-", label=f"{n:,} agents")
    axes[0].set_ylabel("agent-steps per second")
    axes[1].set_ylabel("share of the loop in the exchange")
    for ax in axes:
        ax.set_xlabel("ranks (on 2 cores)")
        ax.set_xticks(sorted({r["ranks"] for r in rows}))
    axes[0].set_yscale("log")
    axes[0].legend(fontsize=7)
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
    parser.add_argument("--ranks", default="1,2,4")
    parser.add_argument("--agents", default="1000,10000,100000")
    parser.add_argument("--asynchronous-agents", default="1000,10000")
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--no-scaling", action="store_true", help="only the ages study")
    parser.add_argument("--no-ages", action="store_true", help="only the scaling table")
    parser.add_argument("--worker", nargs=3, type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker(*args.worker)
        return
    if not args.no_scaling:
        rows = []
        also = set(map(int, args.asynchronous_agents.split(","))) if args.asynchronous_agents else set()
        for n in map(int, args.agents.split(",")):
            for ranks in map(int, args.ranks.split(",")):
                for asynchronous in (False, True) if n in also and ranks > 1 else (False,):
                    rows.append(row(measure(ranks, n, args.steps, asynchronous)))
                    print(table(rows[-1:]).splitlines()[-1], flush=True)
        print(table(rows))
        figure(rows, DOCS / "distributed.png")
        print(f"wrote {DOCS / 'distributed.png'}")
    if not args.no_ages:
        with tempfile.TemporaryDirectory() as work:
            ages_study(Path(work))


if __name__ == "__main__":
    main()
