"""The figure and table of docs/control.md: agents that learn their policies on the pull-away task (4 agents, 3
states, links of a ring up with probability 0.8), networked with each distributed critic, on perfect links and with
30 % of messages lost, beside centralised and independent learners; and Zhang et al.'s 20-agent setting, networked
(DGTD critic) beside the centralised actor-critic. Every run is what `dgtd learn` runs (the same function, the same
keyed numbers). Usage: python benchmarks/control.py [--seeds 4] [--out docs]"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from dgtd.algorithms import make_algorithm  # noqa: E402
from dgtd.algorithms.actor import SoftmaxActor  # noqa: E402
from dgtd.channels import Arcs, Lossy  # noqa: E402
from dgtd.graphs import topologies  # noqa: E402
from dgtd.graphs.random import random_edges  # noqa: E402
from dgtd.plots.bands import band  # noqa: E402
from dgtd.problems import team  # noqa: E402
from dgtd.run.learn import LearnSettings, learn  # noqa: E402

CRITICS = {"dgtd": "C0", "consensus-td0": "C1", "consensus-tdrc": "C2", "td-tracking": "C3"}  # and their colours


def one(mdp, network, critic: str, actor: str, seeds: int, iterations: int, loss: float):
    channel = None
    if loss:
        channel = Lossy(np.full(Arcs.of(network.base.edges, network.n_nodes).n_arcs, loss))
    settings = LearnSettings(iterations=iterations, seeds=seeds, actor=actor, checkpoints=20)
    start = time.perf_counter()
    result = learn(mdp, network, make_algorithm(critic, alpha0=1.0, beta=100.0), SoftmaxActor(), settings, channel)
    return result, time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--out", default="docs")
    args = parser.parse_args()
    mdp = team.pull_away()
    net = random_edges(topologies.ring(4), 0.8)
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.2))
    rows = []
    for loss, style in ((0.0, "-"), (0.3, "--")):
        for critic, colour in CRITICS.items():
            r, seconds = one(mdp, net, critic, "networked", args.seeds, 10_000, loss)
            label = f"{critic}, loss {loss:.0%}"
            line = band(axes[0], r.steps, r.metrics["return"], label, colour)
            line.set_linestyle(style)
            axes[1].plot(np.median(r.metrics["bits"], axis=1) / 8e6, np.median(r.metrics["return"], axis=1), style,
                         color=line.get_color(), label=label)  # fmt: skip
            rows.append((f"networked, {critic} critic", f"{loss:.0%}", r, seconds))
    for actor in ("centralised", "independent"):
        r, seconds = one(mdp, net, "dgtd", actor, args.seeds, 10_000, 0.0)
        band(axes[0], r.steps, r.metrics["return"], f"{actor} (dgtd critic)", "k" if actor[0] == "c" else "C7")
        rows.append((f"{actor}, dgtd critic", "0%", r, seconds))
    axes[0].axhline(2.0, color="k", linestyle=":", label="J* = 2")
    axes[0].set(xlabel="step (one sample per agent, one round of messages)", ylabel="J(pi_t), exact",
                title="pull-away: 4 agents, ring up w.p. 0.8")  # fmt: skip
    axes[1].set(xlabel="megabytes delivered (all agents)", ylabel="J(pi_t), median over seeds", title="against bits")
    axes[0].legend(fontsize=7)
    zhang = team.zhang_20()
    complete = random_edges(topologies.complete(20), 0.2)
    for actor in ("networked", "centralised"):
        r, seconds = one(zhang, complete, "dgtd", actor, args.seeds, 20_000, 0.0)
        band(axes[2], r.steps, r.metrics["return"], f"{actor} (dgtd critic)")
        rows.append((f"zhang-20, {actor}", "0%", r, seconds))
    axes[2].axhline(zhang.best_return()[0], color="k", linestyle=":", label="J*")
    axes[2].set(xlabel="step", ylabel="J(pi_t), exact", title="Zhang et al.'s 20 agents, links w.p. 0.2 (complete)")
    axes[2].legend(fontsize=7)
    fig.tight_layout()
    Path(args.out).mkdir(exist_ok=True)
    fig.savefig(Path(args.out) / "control.png", dpi=110)
    print("| learners | loss | J at 2 000 | J at the end | least p(best) at the end | critic error | seconds |")
    print("|---|---|---|---|---|---|---|")
    for name, loss, r, seconds in rows:
        J = np.median(r.metrics["return"], axis=1)
        early = J[np.searchsorted(r.steps, 2000)]
        least = r.metrics["best_probability"][-1]
        shown = f"{np.nanmin(least):.3f}" if np.isfinite(least).all() else "-"
        error = np.median(r.metrics["critic_error"][-1])
        print(f"| {name} | {loss} | {early:.3f} | {J[-1]:.3f} | {shown} | {error:.2g} | {seconds:.0f} |")


if __name__ == "__main__":
    main()
