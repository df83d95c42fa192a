"""The wireless-access benchmark of Qu, Wierman and Li's scalable actor-critic (`dgtd.problems.wireless`,
`dgtd.run.scalable`) at its published size and settings: 3 x 4 cells, 2 users a cell (24 agents), 6 access points,
deadline 2, arrivals 0.5, kappa 1, gamma 0.7, horizon 10, 120 000 episodes; their public code's steps (each critic's
table kept over episodes, alpha = 1 / sqrt((m mod 100) T + t), the actor's 5 / sqrt(m mod 100 + 1) on the mean of the
truncated values: 5 / n on their sum here). Every ``--every`` episodes the policies' mean per-agent discounted return
(1/n) sum_i sum_{t<T} gamma^t r_i(t) is estimated from ``--rollouts`` keyed rollouts, as their code measures it;
beside it the best of their 20 ALOHA-like heuristics (send probability 0, 0.05, .., 0.95) on the same numbers, and
their published curve (their repository's data file). Writes docs/wireless.png and benchmarks/results/wireless.json.

Usage: python benchmarks/wireless.py [--episodes 120000] [--every 2000] [--rollouts 400] [--seeds 1]
[--height 3 --width 4 --users 2] [--loss P] [--forget] [--out docs] (a shorter or lossy run writes its numbers only)

Under ``mpiexec -n R`` the agents are spread over the ranks (`dgtd.run.layout.learner_layout`; the numbers are one
process's) and each rank's peak memory is reported: a rank's memory as the ranks grow at a fixed number of agents a
rank (docs/control.md)."""

from __future__ import annotations

import argparse
import json
import resource
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from tqdm import tqdm  # noqa: E402

from dgtd.backends import mpi  # noqa: E402
from dgtd.problems.wireless import grid  # noqa: E402
from dgtd.run.networked import NetworkedConfig, heuristic, learn_networked  # noqa: E402

# Their published curve (yihenglin97/Networked-MARL, WirelessAccess/data/Tabular-Access-3-4-1.txt): the mean per-agent
# discounted return at episodes 0, 2 000, .., 120 000, each from 400 rollouts
PUBLISHED = (
    0.020078, 0.021051, 0.023801, 0.024598, 0.027024, 0.029291, 0.034220, 0.036620, 0.042617, 0.047452, 0.049064,
    0.055711, 0.058386, 0.068307, 0.074373, 0.076974, 0.083572, 0.090158, 0.094590, 0.100553, 0.102344, 0.109538,
    0.114466, 0.122124, 0.131270, 0.135291, 0.143573, 0.150482, 0.151782, 0.157805, 0.160653, 0.165342, 0.176076,
    0.175890, 0.184463, 0.186417, 0.182227, 0.190985, 0.184591, 0.193089, 0.198337, 0.193286, 0.203525, 0.200555,
    0.201798, 0.203909, 0.211421, 0.216754, 0.218385, 0.217365, 0.218383, 0.222536, 0.230217, 0.220459, 0.231400,
    0.238660, 0.239292, 0.235691, 0.237121, 0.240485, 0.241448,
)  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=120_000)
    parser.add_argument("--every", type=int, default=2_000)
    parser.add_argument("--rollouts", type=int, default=400)
    parser.add_argument("--seeds", type=int, default=1)
    parser.add_argument("--height", type=int, default=3)
    parser.add_argument("--width", type=int, default=4)
    parser.add_argument("--users", type=int, default=2)
    parser.add_argument("--loss", type=float, default=0.0, help="messages within kappa hops lost with this probability")
    parser.add_argument("--forget", action="store_true", help="the critics' tables from 0 at each restart")
    parser.add_argument("--out", type=Path, default=Path("docs"))
    args = parser.parse_args()
    task = grid(args.height, args.width, args.users)
    config = NetworkedConfig(episodes=args.episodes, seeds=args.seeds, every=args.every, rollouts=args.rollouts,
                             loss=args.loss, forget=args.forget)  # (the published steps: the defaults)  # fmt: skip
    if mpi.rank() == 0:  # (the heuristics' rollouts once, by the process that reports them)
        best = heuristic("wireless-access", task, config)
        aloha = list(best["tried"].values())
        print(f"{task.n_agents} agents: best ALOHA-like heuristic {float(best['return'].mean()):.4f} "
              f"({best['policy']})", flush=True)  # fmt: skip
    with tqdm(total=args.episodes, unit="episode", mininterval=2.0, disable=mpi.rank() > 0) as bar:
        result = learn_networked(task, config, bar.update)
    curve, episodes, seconds = result["return"], result["episodes"], result["seconds"]  # (C + 1, B): the start first
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # MB (Linux: kB)
    peaks = mpi.world().gather(peak, root=0) if mpi.spread() else [peak]  # (each rank's)
    if mpi.rank() > 0:
        return
    print(f"learnt: {curve[0].mean():.4f} -> {curve[-1].mean():.4f} in {args.episodes:,} episodes, {seconds:.0f} s, "
          f"peak {max(peaks):.0f} MB a rank ({', '.join(f'{p:.0f}' for p in peaks)}) on {len(peaks)}")  # fmt: skip
    record = {
        "agents": task.n_agents, "episodes": episodes.tolist(), "return": curve.tolist(), "aloha": aloha,
        "aloha_best": float(best["return"].mean()), "aloha_send": best["policy"], "seconds": seconds, "peak_mb": peak,
        "seeds": args.seeds, "rollouts": args.rollouts, "loss": args.loss, "ranks": len(peaks), "peaks_mb": peaks,
        "forget": args.forget,
    }  # fmt: skip
    results = Path(__file__).parent / "results"
    results.mkdir(exist_ok=True)
    name = f"wireless-{task.n_agents}" + (f"-loss{args.loss:g}" if args.loss else "")
    if args.episodes != 120_000:
        name += f"-{args.episodes}"
    name += f"-ranks{len(peaks)}" if len(peaks) > 1 else ""
    (results / f"{name}.json").write_text(json.dumps(record, indent=1))
    if not args.loss and args.episodes == 120_000:
        figure(episodes, curve, float(best["return"].mean()), task.n_agents, args.out / f"{name}.png")


def figure(episodes, curve, aloha: float, n: int, path: Path) -> None:
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    ax.plot(episodes, curve.mean(axis=1), label=f"dgtd, scalable actor-critic ({curve.shape[1]} seed(s))")
    if n == 24:
        ax.plot(np.arange(len(PUBLISHED)) * 2000, PUBLISHED, "--", label="Qu et al.'s published curve")
    ax.axhline(aloha, color="g", label="best ALOHA-like heuristic")
    ax.set_xlabel("episodes")
    ax.set_ylabel("mean per-agent discounted return")
    ax.set_title(f"wireless access, {n} agents, kappa 1")
    ax.legend(loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
