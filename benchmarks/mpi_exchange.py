"""Which way of exchanging a step's cross-rank messages is faster: one neighbourhood collective, or persistent
point-to-point requests (what `dgtd.backends.mpi.Partition.exchange` chose between).

    python benchmarks/mpi_exchange.py [--ranks 2,4] [--doubles 16,256,4096] [--rounds 20000] [--repeats 3]

Each rank of ``mpiexec -n R`` (this machine, loopback) has its two ring neighbours on a distributed-graph
communicator and, per round, sends each of them ``doubles`` numbers and receives theirs: by ``Neighbor_alltoallv``
(as the runtime does), or by persistent requests (``Send_init``/``Recv_init`` once, then ``Startall``/``Waitall``
every round). The two are interleaved ``--repeats`` times; prints the rounds per second of each (the slowest rank's),
as a Markdown table with the range over the repeats.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path


def worker(doubles: int, rounds: int) -> None:
    import numpy as np
    from mpi4py import MPI

    world = MPI.COMM_WORLD
    R, r = world.Get_size(), world.Get_rank()
    ring = sorted({(r - 1) % R, (r + 1) % R})
    comm = world.Create_dist_graph_adjacent(ring, ring, reorder=False)
    out, into = np.full(doubles * len(ring), float(r)), np.empty(doubles * len(ring))
    counts, offsets = [doubles] * len(ring), [doubles * i for i in range(len(ring))]

    def collective() -> None:
        comm.Neighbor_alltoallv([out, counts, offsets, MPI.DOUBLE], [into, counts, offsets, MPI.DOUBLE])

    requests = [comm.Send_init(out[o : o + doubles], dest=k, tag=1) for k, o in zip(ring, offsets)]
    requests += [comm.Recv_init(into[o : o + doubles], source=k, tag=1) for k, o in zip(ring, offsets)]

    def persistent() -> None:
        MPI.Prequest.Startall(requests)
        MPI.Request.Waitall(requests)

    seconds = {}
    for name, exchange in (("neighbourhood collective", collective), ("persistent requests", persistent)):
        for _ in range(rounds // 10):  # warm up (connections, caches) before timing
            exchange()
        world.Barrier()
        t0 = time.perf_counter()
        for _ in range(rounds):
            exchange()
        seconds[name] = world.allreduce(time.perf_counter() - t0, op=MPI.MAX)
        expected = sorted(float(k) for k in ring)
        assert sorted(set(into.tolist())) == sorted(set(expected)), "the neighbours' numbers did not arrive"
    if r == 0:
        print(json.dumps({name: rounds / s for name, s in seconds.items()}))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ranks", default="2,4")
    parser.add_argument("--doubles", default="16,256,4096")
    parser.add_argument("--rounds", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--worker", nargs=2, type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker(*args.worker)
        return
    mpiexec = str(Path(sys.executable).parent / "mpiexec")
    print("| ranks | doubles a neighbour | neighbourhood collective (rounds/s) | persistent requests (rounds/s) |")
    print("| ---: | ---: | ---: | ---: |")
    for ranks in map(int, args.ranks.split(",")):
        for doubles in map(int, args.doubles.split(",")):
            got: dict = {}
            for _ in range(args.repeats):
                cmd = [mpiexec, "-n", str(ranks), sys.executable, __file__, "--worker", str(doubles), str(args.rounds)]
                done = subprocess.run(cmd, capture_output=True, text=True, timeout=600, check=True)
                for name, rate in json.loads(done.stdout.strip().splitlines()[-1]).items():
                    got.setdefault(name, []).append(rate)
            cells = [f"{min(v):,.0f}-{max(v):,.0f}" for v in got.values()]
            print(f"| {ranks} | {doubles:,} | {' | '.join(cells)} |", flush=True)


if __name__ == "__main__":
    main()
