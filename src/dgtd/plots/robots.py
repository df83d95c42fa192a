"""Figures of the patrol world (the paper's Example 2, its Fig. 4): value maps as heat maps, robots and links.

- ``maps.png``: every agent's final map beside the reference w*, one colour scale, the regions outlined;
- ``reference.png``: the reference w*, the stationary distribution of the estimated chain, and the
  centralised TD estimate from the same samples;
- ``snapshots.png``: a strip over time (columns) of every agent's map (rows) with the robots, their recent
  paths and the links that are up;
- ``patrol.gif``: the same as an animation; ``curves.png``: per-agent error, correlation with w* and consensus.
Every file is written atomically (temporary file, then rename).
"""

from __future__ import annotations

import io
import os
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402

from dgtd.plots.bands import band  # noqa: E402
from dgtd.run.results import atomic_write, file_mode  # noqa: E402
from dgtd.scenarios.robots import PatrolReport, map_correlation  # noqa: E402

AGENT_COLOURS = ("tab:blue", "tab:red", "black", "tab:green", "tab:purple", "tab:orange")
CMAP = "viridis"


def agent_colour(i: int) -> str:
    return AGENT_COLOURS[i % len(AGENT_COLOURS)]


def _save(fig, path: Path, dpi: int = 110) -> None:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    atomic_write(path, buf.getvalue())


def draw_map(ax, world, values, vmin, vmax, cmap=CMAP):
    """A grid map (S,) as a heat map in metres, origin at the lower left, with every region outlined."""
    im = ax.imshow(
        np.asarray(values).reshape(world.grid, world.grid),
        origin="lower",
        cmap=cmap,
        vmin=vmin,
        vmax=vmax,
        extent=(0, world.size, 0, world.size),
        interpolation="nearest",
    )
    for i, (x0, y0, x1, y1) in enumerate(world.regions):
        for colour, lw in (
            ("white", 3.2),
            (agent_colour(i), 1.6),
        ):  # a white halo keeps the outline visible on any colour
            ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, ec=colour, lw=lw))
    ax.set_xticks([0, world.size / 2, world.size])
    ax.set_yticks([0, world.size / 2, world.size])
    ax.tick_params(labelsize=7)
    return im


def draw_robots(ax, trail, up, edges, radius=None):
    """Robots at the last row of ``trail`` (L, N, 2), their recent paths, and the links ``up`` (E,) as lines.

    Returns the artists, so that an animation can update them."""
    x = trail[-1]
    arts = []
    for e, (u, v) in enumerate(edges):
        (line,) = ax.plot(
            [x[u, 0], x[v, 0]], [x[u, 1], x[v, 1]], color="white", lw=2.0, ls="-", zorder=4, visible=bool(up[e])
        )
        arts.append(line)
    for i in range(x.shape[0]):
        (path,) = ax.plot(trail[:, i, 0], trail[:, i, 1], color=agent_colour(i), lw=1.0, alpha=0.9, zorder=5)
        (dot,) = ax.plot(x[i, 0], x[i, 1], "o", ms=7, mfc=agent_colour(i), mec="white", mew=1.5, zorder=6)
        arts += [path, dot]
    return arts


def plot_maps(world, result, path: Path, seed: int = 0) -> None:
    """Final maps of every agent (seed ``seed``) beside the reference w*: the paper's Fig. 4 plus the reference."""
    N = result.w_last.shape[1]
    W = result.w_last[seed]
    vmax = float(max(W.max(), result.w_star.max()))
    corr = map_correlation(W, result.w_star)
    fig, axes = plt.subplots(1, N + 1, figsize=(3.3 * (N + 1), 3.5), constrained_layout=True)
    for i in range(N):
        im = draw_map(axes[i], world, W[i], 0.0, vmax)
        axes[i].set_title(
            f"agent {i + 1} (senses the {agent_colour(i).replace('tab:', '')} region)\n"
            f"correlation with w*: {corr[i]:.3f}",
            fontsize=9,
            color=agent_colour(i),
        )
    draw_map(axes[N], world, result.w_star, 0.0, vmax)
    axes[N].set_title("reference w* (estimated chain)\naverage reward of all robots", fontsize=9)
    axes[0].set_xlabel("x (m)", fontsize=8)
    axes[0].set_ylabel("y (m)", fontsize=8)
    fig.colorbar(im, ax=axes, shrink=0.85, label="value")
    fig.suptitle(f"value maps after {int(result.steps[-1]):,} iterations (seed {seed})", fontsize=10)
    _save(fig, path)


def plot_reference(world, reference, path: Path) -> None:
    """The reference w*, the stationary distribution d of the estimated chain, and TD(0) on the same samples."""
    fig, axes = plt.subplots(1, 3, figsize=(11, 3.5), constrained_layout=True)
    vmax = float(max(reference.w_star.max(), reference.w_td.max()))
    im0 = draw_map(axes[0], world, reference.w_star, 0.0, vmax)
    axes[0].set_title("exact w* of the estimated chain", fontsize=9)
    im1 = draw_map(axes[1], world, reference.d, 0.0, float(reference.d.max()), cmap="Greys")
    axes[1].set_title("stationary distribution d", fontsize=9)
    draw_map(axes[2], world, reference.w_td, 0.0, vmax)
    gap = np.abs(reference.w_td - reference.w_star).max() / np.abs(reference.w_star).max()
    axes[2].set_title(f"centralised TD(0), same samples\nmax |w_TD - w*| = {gap:.2%} of max w*", fontsize=9)
    fig.colorbar(im0, ax=[axes[0], axes[2]], shrink=0.85, label="value")
    fig.colorbar(im1, ax=axes[1], shrink=0.85, label="probability")
    fig.suptitle(
        f"reference from {reference.n_transitions:,} simulated transitions "
        f"({reference.teams * world.n_robots} robots x {reference.steps:,} steps)",
        fontsize=10,
    )
    _save(fig, path)


def _recorded(source) -> dict:
    """Step -> (trail, links) of seed 0 at every block end the source recorded."""
    return {k: (trail, up) for k, trail, up in source.snapshots}


def pick_steps(steps: np.ndarray, available, n: int, first: int = 100) -> list[int]:
    """About n checkpoint steps, log-spaced from ``first`` to the last, that have recorded positions."""
    cand = np.array([s for s in steps if int(s) in available])
    if cand.size == 0:
        return []
    targets = np.geomspace(min(first, cand[-1]), cand[-1], n)
    idx = np.unique([int(np.abs(np.log(cand) - np.log(t)).argmin()) for t in targets])
    return [int(cand[i]) for i in idx]


def plot_snapshots(world, network, result, source, path: Path, n: int = 6) -> bool:
    """Rows: agents; columns: moments of the run. Each panel: the agent's map then, robots, paths and links."""
    if result.w_trace is None or not source.snapshots:
        return False
    rec = _recorded(source)
    chosen = pick_steps(result.steps, rec, n)
    N = result.w_last.shape[1]
    vmax = float(max(result.w_star.max(), result.w_last[0].max()))
    fig, axes = plt.subplots(
        N, len(chosen), figsize=(2.3 * len(chosen), 2.35 * N), squeeze=False, constrained_layout=True
    )
    index = {int(s): c for c, s in enumerate(result.steps)}
    for col, k in enumerate(chosen):
        trail, up = rec[k]
        for i in range(N):
            ax = axes[i, col]
            im = draw_map(ax, world, result.w_trace[index[k], 0, i], 0.0, vmax)
            draw_robots(ax, trail, up, network.base.edges)
            ax.set_xlim(0, world.size)
            ax.set_ylim(0, world.size)
            if i == 0:
                ax.set_title(f"k = {k:,}", fontsize=9)
            if col == 0:
                ax.set_ylabel(f"agent {i + 1}", color=agent_colour(i), fontsize=10)
    fig.colorbar(im, ax=axes, shrink=0.6, label="value")
    fig.suptitle(
        "each agent's map forming (seed 0); dots: robots, lines: links up (distance <= "
        f"{network.radius:g} m), tails: last {trail.shape[0]} steps",
        fontsize=10,
    )
    _save(fig, path)
    return True


def write_gif(world, network, result, source, path: Path, n_frames: int = 60, fps: int = 6) -> bool:
    """The snapshots as an animation: every agent's map with the robots and links, at log-spaced moments."""
    if result.w_trace is None or not source.snapshots:
        return False
    from matplotlib.animation import FuncAnimation, PillowWriter

    rec = _recorded(source)
    chosen = pick_steps(result.steps, rec, n_frames, first=50)
    index = {int(s): c for c, s in enumerate(result.steps)}
    N = result.w_last.shape[1]
    vmax = float(max(result.w_star.max(), result.w_last[0].max()))
    fig, axes = plt.subplots(1, N, figsize=(2.6 * N + 0.8, 3.1), squeeze=False)
    fig.subplots_adjust(left=0.05, right=0.88, bottom=0.08, top=0.80, wspace=0.18)
    axes = axes[0]
    ims: list = []
    robots: list = []
    for i, ax in enumerate(axes):
        ims.append(draw_map(ax, world, result.w_trace[index[chosen[0]], 0, i], 0.0, vmax))
        ax.set_title(f"agent {i + 1}", color=agent_colour(i), fontsize=9)
        ax.set_xlim(0, world.size)
        ax.set_ylim(0, world.size)
    fig.colorbar(ims[0], cax=fig.add_axes((0.90, 0.12, 0.015, 0.64)), label="value")

    def draw(frame):
        k = chosen[frame]
        trail, up = rec[k]
        for i in range(N):
            ims[i].set_data(result.w_trace[index[k], 0, i].reshape(world.grid, world.grid))
        for a in robots:
            a.remove()
        robots.clear()
        for i in range(N):
            robots.extend(draw_robots(axes[i], trail, up, network.base.edges))
        fig.suptitle(
            f"each agent's value map at k = {k:,} (seed 0)\ndots: robots; white lines: links up "
            f"(within {network.radius:g} m)",
            fontsize=9,
        )
        return ims + robots

    anim = FuncAnimation(fig, draw, frames=len(chosen), init_func=lambda: [], blit=False)
    fd, tmp = tempfile.mkstemp(dir=Path(path).parent, prefix=f".{Path(path).name}.", suffix=".gif")
    os.close(fd)
    try:
        anim.save(tmp, writer=PillowWriter(fps=fps), dpi=90)
        os.chmod(tmp, file_mode())
        os.replace(tmp, path)
    finally:
        plt.close(fig)
        Path(tmp).unlink(missing_ok=True)
    return True


def plot_curves(result, d: np.ndarray, path: Path) -> bool:
    """Against k: each agent's relative errors and correlation with w* (median over seeds, 90 % band), consensus.

    The sup-norm error is set by the rarest cells; the D-weighted one, |w_i - w*|_D / |w*|_D with d the
    stationary distribution, is the error where the robots actually are."""
    if result.w_trace is None:
        return False
    x = result.steps
    N = result.w_last.shape[1]
    corr = map_correlation(result.w_trace, result.w_star)  # (C, B, N)
    err_d = np.sqrt((d * (result.w_trace - result.w_star) ** 2).sum(-1) / (d * result.w_star**2).sum())
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8), constrained_layout=True)
    for i in range(N):
        band(axes[0], x, result.agent_error_last[:, :, i], f"agent {i + 1}, sup norm", color=agent_colour(i))
        axes[0].plot(
            x,
            np.median(err_d[:, :, i], axis=1),
            color=agent_colour(i),
            ls="--",
            lw=1.0,
            label=f"agent {i + 1}, D-weighted",
        )
        band(axes[1], x, corr[:, :, i], f"agent {i + 1}", color=agent_colour(i))
    axes[0].set_yscale("log")
    axes[0].set_title("relative error of the last iterate")
    axes[0].set_ylabel("|w_i - w*| / |w*| (sup norm; D-weighted)")
    axes[1].set_ylabel("Pearson correlation")
    axes[2].set_ylabel("sum_i |w_i - mean_j w_j|^2")
    axes[1].set_title("correlation of agent i's map with w*")
    axes[1].set_ylim(min(0.0, float(np.nanmin(corr))), 1.0)
    cons = result.metrics["consensus"]
    # exact zeros (before any link) left out
    band(axes[2], x, np.where(cons > 0, cons, np.nan), "sum_i |w_i - mean w|^2")
    axes[2].set_yscale("log")
    axes[2].set_title("consensus error")
    for ax in axes:
        ax.set_xscale("log")
        ax.set_xlabel("iteration k")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    _save(fig, path)
    return True


def write_figures(world, network, reference, result, source, out) -> list[str]:
    """All the patrol world's figures into ``out``; returns the names written."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    plot_maps(world, result, out / "maps.png")
    plot_reference(world, reference, out / "reference.png")
    names = ["maps.png", "reference.png"]
    if plot_snapshots(world, network, result, source, out / "snapshots.png"):
        names.append("snapshots.png")
    if write_gif(world, network, result, source, out / "patrol.gif"):
        names.append("patrol.gif")
    if plot_curves(result, reference.d, out / "curves.png"):
        names.append("curves.png")
    return names


def report_figures(report, result, source, out) -> list[str]:
    """`write_figures` for a patrol world's `PatrolReport`; nothing for another report."""
    if not isinstance(report, PatrolReport):
        return []
    return write_figures(report.world, report.network, report.reference, result, source, out)
