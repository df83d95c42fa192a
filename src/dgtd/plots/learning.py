"""The figures of a learning run: the exact return of the agents' policies against samples and against messages
sent, with its band over seeds and the best return J*, and the critics' error against the exact critic."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

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
        error = result.metrics["critic_error"]
        band(ay, result.steps, error, "critics' error")
        shown = (error > 0) & np.isfinite(error)  # (a diverged run has none: a log scale would fail)
        ay.set(xlabel="step", ylabel="relative error", yscale="log" if shown.any() else "linear",
               title="the critics' error against W*(pi_t)")  # fmt: skip
    fig.tight_layout()
    fig.savefig(Path(out) / "returns.png", dpi=110)
    plt.close(fig)
    return "returns.png"


def learners_figure(out: Path, results: dict, title: str) -> str:
    """learners.png: each learners' exact return against steps (median and band over seeds) and against the bits
    delivered (median), J* where known."""
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


LABELS = ("actor", "learners")  # metrics.csv's first column in a learning run's folder, and in a learners' comparison


def is_learning(directory: Path) -> bool:
    """Whether ``directory`` holds a learning run's or a learners' comparison's metrics.csv."""
    try:
        with open(Path(directory) / "metrics.csv") as f:
            return f.readline().split(",")[0] in LABELS
    except (OSError, UnicodeDecodeError):
        return False


def learning_figures_again(directory: Path) -> list[Path]:
    """The figures of a learning run's folder (returns.png) or a learners' comparison's (learners.png), drawn again
    from its metrics.csv and summary.json alone."""
    from dgtd.files import read_json
    from dgtd.plots import read_metrics

    directory = Path(directory)
    path, fix = directory / "metrics.csv", "run it again"
    with open(path) as f:
        column = f.readline().split(",")[0]  # (`is_learning`: one of `LABELS`)
    steps, results, _ = read_metrics(path, fix, column)
    summary = (
        read_json(directory / "summary.json", "results file", fix) if (directory / "summary.json").exists() else {}
    )
    info = {"estimated": bool(summary.get("return_estimated", False)), "objective": summary.get("objective")}
    shown = {label: _Saved(steps, metrics, summary.get("return_best"), info) for label, metrics in results.items()}
    name = summary.get("task", directory.name)
    if column == "learners":
        return [directory / learners_figure(directory, shown, name)]
    label, result = next(iter(shown.items()))
    return [directory / learning_figure(directory, result, f"{name}, {label}")]


class _Saved:
    """A learning result's figures' inputs, read back."""

    def __init__(self, steps, metrics, return_best, info):
        self.steps, self.metrics, self.return_best, self.info = steps, metrics, return_best, info


def learning_sweep_figure(jobs: dict, points: dict, path: Path) -> bool:
    """returns.png of a sweep of learning runs: each job's return against steps (median and band over seeds); False
    where the jobs are not learning runs (no return metric)."""
    if not any("return" in metrics for _, metrics in jobs.values()):
        return False
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for job, (steps, metrics) in jobs.items():
        label = ", ".join(f"{k}={v}" for k, v in points.get(job, {}).items() if v is not None) or job
        band(ax, steps, metrics["return"], label)
    ax.set(xlabel="step", ylabel="return J (exact, or estimated in a simulator)")
    ax.set_title(f"{len(jobs)} learning jobs, {BAND_WORDS}", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def networked_figure(path: Path, results: dict, heuristic: dict | None, task: str) -> str:
    """returns.png of networked learners: each one's evaluated return against episodes (median and band over seeds),
    and the task's heuristic at its best."""
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for label, r in results.items():
        band(ax, np.asarray(r["episodes"]), np.asarray(r["return"]), label)
    if heuristic is not None:
        ax.axhline(float(np.median(heuristic["return"])), color="g", label=f"heuristic: {heuristic['policy']}")
    ax.set(xlabel="episodes", ylabel="mean per-agent discounted return")
    ax.set_title(f"{task}, {next(iter(results.values()))['agents']} agents\n{BAND_WORDS}", fontsize=9)
    ax.legend(loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return Path(path).name
