"""What a link model costs: agent-steps per second of the compiled kernels with the perfect channel and with lost,
late, asleep or compressed messages, on bench cases B (16 agents, 64 features, 32 seeds) and D (10 000 agents, one
seed), in interleaved rounds (this machine is shared: the median of each, and the range of the paired ratios to the
perfect channel, are what to read).

    python benchmarks/links_cost.py [--rounds 3] [--cases B,D] [--models loss,delay,wake,bits,feedback]

Prints a Markdown table (docs/links.md quotes it)."""

from __future__ import annotations

import argparse

import numpy as np

from dgtd.channels import Arcs, Imperfect, Lossy, Perfect
from dgtd.cli.bench import CASES, bench_algorithm, time_run


def models(arcs: Arcs) -> dict:
    """{label: channel} of the models measured against the perfect channel."""
    none = Lossy(np.zeros(arcs.n_arcs))
    return {
        "loss": ("loss 0.1", Lossy(np.full(arcs.n_arcs, 0.1))),
        "delay": ("delay 5", Imperfect(none, delay=5)),
        "wake": ("wake 0.5", Imperfect(none, wake=np.full(arcs.n_agents, 0.5))),
        "bits": ("8 bits", Imperfect(none, bits=8)),
        "feedback": ("4 bits, error feedback", Imperfect(none, bits=4, error_feedback=True)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--algorithms", default="dgtd,consensus-td0")
    parser.add_argument("--cases", default="B,D")
    parser.add_argument("--models", default="loss,delay,wake,bits,feedback")
    args = parser.parse_args()
    rows = []
    for key in args.cases.split(","):
        case = CASES[key]
        problem, network, dgtd = case.make()
        arcs = Arcs.of(network.base.edges, network.n_nodes)
        chosen = [models(arcs)[m] for m in args.models.split(",")]
        channels = {"perfect": Perfect(), **dict(chosen)}
        T = case.iterations["numba"]
        for name in args.algorithms.split(","):
            algorithm = bench_algorithm(name, dgtd)
            rates: dict[str, list[float]] = {c: [] for c in channels}
            for _ in range(args.rounds):
                for c, channel in channels.items():
                    secs = time_run(problem, network, algorithm, case.seeds, T, "numba", 1, channel)[0]
                    rates[c].append(T * case.seeds * problem.n_agents / secs)
            for c in list(channels)[1:]:
                ratio = np.array(rates[c]) / np.array(rates["perfect"])
                perfect, other = np.median(rates["perfect"]) / 1e6, np.median(rates[c]) / 1e6
                rows.append(
                    f"| {key} | {name} | {c} | {perfect:.2f} M | {other:.2f} M | {ratio.min():.2f}-{ratio.max():.2f} |"
                )
                print(rows[-1], flush=True)
    print("| case | algorithm | model | perfect | with the model | model / perfect, paired |")
    print("| --- | --- | --- | ---: | ---: | ---: |")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
