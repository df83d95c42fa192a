"""Chen, Zhou, Chen and Zou's Algorithm 1 (ICML 2022) in dgtd (`dgtd learn chen-6 --scheme chen`) beside their own
code, on their 6-agent setting (`dgtd.problems.team.chen_6`, re-created from their seeds), their sizes and steps for
N = 2 000 (T_c = 50, N_c = 10, T_c' = 10, T_r = 5, alpha = 200, beta = 0.5), to 300 000 samples, 10 seeds: the exact J
of the policies at every iteration (median and 5th-95th percentile over seeds) against samples, and each one's wall
time. Their code (zuopaoyoutao/MACE at e568715, DAC_utils.py) is run where --theirs gives its path: their `DAC` on
their `init(seed_init=0)` MDP, their ring W (0.4, 0.3, 0.3), omega0 after set_seed(5), seed k set before run k, as
their runs() does. Usage: python benchmarks/chen.py [--seeds 10] [--samples 300000] [--theirs DAC_utils.py]
[--out docs]"""

from __future__ import annotations

import argparse
import importlib.util
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from dgtd.graphs import topologies  # noqa: E402
from dgtd.graphs.random import random_edges  # noqa: E402
from dgtd.plots.bands import band  # noqa: E402
from dgtd.problems import team  # noqa: E402
from dgtd.run.chen import ChenSteps, learn_chen  # noqa: E402
from dgtd.run.learn import LearnSettings  # noqa: E402


def ours(seeds: int, samples: int, steps: ChenSteps) -> tuple:
    """(samples at each iteration, J (iterations, seeds), seconds) of dgtd's Algorithm 1, measured every iteration."""
    settings = LearnSettings(samples, seeds, checkpoints=samples // steps.samples, objective="discounted")
    start = time.perf_counter()
    result = learn_chen(team.chen_6(), random_edges(topologies.ring(6), 1.0), steps, settings)
    return result.steps, result.metrics["return"], time.perf_counter() - start  # (the exact measures included)


def theirs(path: Path, seeds: int, samples: int, steps: ChenSteps) -> tuple:
    """(samples at each iteration, J (iterations, seeds), seconds) of their `DAC`, run by their code."""
    spec = importlib.util.spec_from_file_location("DAC_utils", path)
    U = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(U)
    U.set_seed(5)
    omega0 = [np.random.normal(size=(5, 2)) for _ in range(6)]
    setting = U.init(seed_init=0, state_space=range(5), gamma=0.95, W=U.get_W_3diags(d=6, p_central=0.4))
    T = samples // steps.samples + 1  # (their loop runs T - 1 iterations)
    curves, start = [], time.perf_counter()
    for k in range(seeds):
        U.set_seed(k)
        out = U.DAC(
            setting, T=T, Tc=steps.critic_batches, Tc_prime=steps.critic_rounds, Tr=steps.reward_rounds,
            N=steps.batch, Nc=steps.critic_batch, alpha=steps.actor_step, beta=steps.critic_step,
            noise_std=np.repeat(0.1, 6), s0_DAC=0, s0_DTD=0, omega0=omega0, seed_sim_DAC=None, seed_sim_DTD=None,
        )  # fmt: skip
        curves.append(out["Jw"][1:])  # (Jw[t + 1]: the policies after t + 1 iterations)
        print(f"  their seed {k}: J {curves[-1][-1]:.4f}", flush=True)
    return np.arange(1, T) * steps.samples, np.array(curves).T, time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--samples", type=int, default=300_000)
    parser.add_argument("--theirs", type=Path, default=None)
    parser.add_argument("--out", type=Path, default=Path("docs"))
    args = parser.parse_args()
    steps = ChenSteps()
    runs = {"dgtd, --scheme chen": ours(args.seeds, args.samples, steps)}
    if args.theirs is not None:
        runs["their code (MACE, e568715)"] = theirs(args.theirs, args.seeds, args.samples, steps)
    J0 = team.discounted_return(team.chen_6(), list(team.chen_6().policies))
    fig, ax = plt.subplots(figsize=(6, 4))
    print(f"{'run':<30}{'J at the end (median)':>24}{'range':>18}{'seconds':>10}")
    for (label, (x, J, seconds)), colour in zip(runs.items(), ("C0", "C3")):
        band(ax, np.r_[0, x], np.vstack([np.full(J.shape[1], J0), J]), label, colour)
        print(f"{label:<30}{np.median(J[-1]):>24.4f}{f'{J[-1].min():.4f}-{J[-1].max():.4f}':>18}{seconds:>10.1f}")
    ax.axhline(team.best_of(team.chen_6(), "discounted")[0], color="k", linestyle=":", label="J*")
    ax.set_xlabel("samples")
    ax.set_ylabel("J (normalised discounted return)")
    ax.set_title(f"Chen et al.'s Algorithm 1, N = {steps.batch}: median, 5-95 % over {args.seeds} seeds", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(args.out / "chen.png", dpi=120)


if __name__ == "__main__":
    main()
