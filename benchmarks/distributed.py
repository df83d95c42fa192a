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
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

DOCS = Path(__file__).resolve().parents[1] / "docs"
FEATURES, STATES = 8, 30


def worker(n_agents: int, steps: int) -> None:
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
    settings = RunSettings(iterations=steps, seeds=1, checkpoints=1, backend="numpy", block_size=steps)
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
        print(json.dumps({"agents": n_agents, "ranks": mpi.size(), "steps": steps, "per_rank": every}), flush=True)


def measure(ranks: int, n_agents: int, steps: int) -> dict:
    mpiexec = Path(sys.executable).parent / "mpiexec"
    cmd = [str(mpiexec), "-n", str(ranks), sys.executable, __file__, "--worker", str(n_agents), str(steps)]
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
        "| agents | ranks | rounds/s | agent-steps/s | own agents | drawn on every rank | exchange | gather | "
        "peak memory a rank, per agent | setup (s) |",
        "| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in rows:
        if r["ranks"] == 1:  # one process: the plain reference kernel, nothing split or exchanged
            r = {**r, "own": float("nan"), "replicated": float("nan"), "exchange": float("nan"), "gather": float("nan")}
        pct = lambda x, digits=0: "-" if x != x else f"{x:.{digits}%}"  # noqa: E731  (NaN: one process)
        lines.append(
            f"| {r['agents']:,} | {r['ranks']} | {r['rounds']:,.1f} | {r['agent_steps'] / 1e6:.3f} M | "
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
        pts = sorted((r for r in rows if r["agents"] == n), key=lambda r: r["ranks"])
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ranks", default="1,2,4")
    parser.add_argument("--agents", default="1000,10000,100000")
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--worker", nargs=2, type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker(*args.worker)
        return
    rows = []
    for n in map(int, args.agents.split(",")):
        for ranks in map(int, args.ranks.split(",")):
            rows.append(row(measure(ranks, n, args.steps)))
            print(table(rows[-1:]).splitlines()[-1], flush=True)
    print(table(rows))
    figure(rows, DOCS / "distributed.png")
    print(f"wrote {DOCS / 'distributed.png'}")


if __name__ == "__main__":
    main()
