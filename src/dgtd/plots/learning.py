"""The figures of a learning run: the exact return of the agents' policies against samples and against messages
sent, with its band over seeds and the best return J*, and the critics' error against the exact critic."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from dgtd.plots.bands import BAND_WORDS, band  # noqa: E402


def learning_figure(out: Path, result, title: str) -> str:
    """returns.png: J(pi_t) against steps (samples per agent) with J*, and the critics' error (log scale); in a
    simulator (no model: ``result.info["estimated"]``), the team's mean reward a step estimated from the run's own
    steps, and the policies' entropy."""
    fig, (ax, ay) = plt.subplots(1, 2, figsize=(11, 4))
    estimated = result.info.get("estimated", False)
    band(
        ax,
        result.steps,
        result.metrics["return"],
        "mean reward since the last checkpoint" if estimated else "J(pi_t), exact",
    )
    if result.return_best is not None:
        ax.axhline(result.return_best, color="k", linestyle="--", label="J*, the best joint policy")
    ax.set(xlabel="step (one sample per agent)", ylabel="average team reward")
    ax.set_title(f"{title}\n{BAND_WORDS}", fontsize=9)
    ax.legend()
    if estimated:
        band(ay, result.steps, result.metrics["entropy"], "policies' entropy")
        ay.set(xlabel="step", ylabel="mean entropy at the observations met (nats)", title="the policies' entropy")
    else:
        band(ay, result.steps, result.metrics["critic_error"], "critics' error")
        ay.set(xlabel="step", ylabel="relative error", yscale="log", title="the critics' error against W*(pi_t)")
    fig.tight_layout()
    fig.savefig(Path(out) / "returns.png", dpi=110)
    plt.close(fig)
    return "returns.png"


def learners_figure(out: Path, results: dict, title: str) -> str:
    """learners.png: each learners' exact return against steps (median and band over seeds) and against the bits
    delivered (median), J* where known."""
    import numpy as np

    fig, (ax, ay) = plt.subplots(1, 2, figsize=(11, 4))
    for label, r in results.items():
        line = band(ax, r.steps, r.metrics["return"], label)
        megabytes, J = np.median(r.metrics["bits"], axis=1) / 8e6, np.median(r.metrics["return"], axis=1)
        silent = not np.any(megabytes)  # (it sends nothing: one point at 0, which a line would not show)
        ay.plot(megabytes[-1:] if silent else megabytes, J[-1:] if silent else J, "o" if silent else "-",
                color=line.get_color(), label=f"{label} (sends nothing)" if silent else label)  # fmt: skip
    best = next(iter(results.values())).return_best
    if best is not None:
        ax.axhline(best, color="k", linestyle=":", label="J*")
    estimated = next(iter(results.values())).info.get("estimated", False)
    ax.set(xlabel="step (one sample per agent)", ylabel="mean reward, estimated" if estimated else "J(pi_t), exact")
    ax.set_title(f"{title}\n{BAND_WORDS}", fontsize=9)
    ay.set(xlabel="megabytes delivered (all agents)", ylabel="median over seeds", title="against what was delivered")
    ax.legend(fontsize=7)
    ay.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(Path(out) / "learners.png", dpi=110)
    plt.close(fig)
    return "learners.png"
