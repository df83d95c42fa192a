"""What a link model costs: agent-steps per second of the compiled kernels with the perfect channel and with lost
messages, on bench cases B (16 agents, 64 features, 32 seeds) and D (10 000 agents, one seed), in interleaved rounds
(this machine is shared: the median of each, and the range of the paired ratios, are what to read).

    python benchmarks/links_cost.py [--rounds 3]

Prints a Markdown table (docs/links.md quotes it)."""

from __future__ import annotations

import argparse

import numpy as np

from dgtd.channels import Arcs, Lossy, Perfect
from dgtd.cli.bench import CASES, bench_algorithm, time_run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--algorithms", default="dgtd,consensus-td0")
    args = parser.parse_args()
    rows = []
    for key in ("B", "D"):
        case = CASES[key]
        problem, network, dgtd = case.make()
        arcs = Arcs.of(network.base.edges, network.n_nodes)
        channels = {"perfect": Perfect(), "loss 0.1": Lossy(np.full(arcs.n_arcs, 0.1))}
        T = case.iterations["numba"]
        for name in args.algorithms.split(","):
            algorithm = bench_algorithm(name, dgtd)
            rates = {c: [] for c in channels}
            for _ in range(args.rounds):
                for c, channel in channels.items():
                    secs = time_run(problem, network, algorithm, case.seeds, T, "numba", 1, channel)[0]
                    rates[c].append(T * case.seeds * problem.n_agents / secs)
            ratio = np.array(rates["loss 0.1"]) / np.array(rates["perfect"])
            perfect, lossy = (np.median(rates[c]) / 1e6 for c in channels)
            rows.append(f"| {key} | {name} | {perfect:.2f} M | {lossy:.2f} M | {ratio.min():.2f}-{ratio.max():.2f} |")
            print(rows[-1], flush=True)
    print("| case | algorithm | perfect | loss 0.1 | lossy / perfect, paired |")
    print("| --- | --- | ---: | ---: | ---: |")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
