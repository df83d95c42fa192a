"""The paper's Example 2: robots patrolling a square area, each sensing one danger region, seen on a grid.

World (paper section 'Simulation', Example 2): N robots move in [0, size]^2 as single integrators
x' = u = -h (x - r_i) toward a waypoint r_i drawn uniformly in the area (the control law of Panagou et al.,
which converges to r_i); once |x - r_i| <= arrival_radius a new waypoint is drawn. Robots do not interfere,
so the N robots are independent copies of one chain, observed on a grid x grid partition (tabular features,
Phi = I): the paper's scenario 2, each agent its own state. Robot i earns ``reward`` (100) while its cell
lies in region i, the region only its sensor detects; every agent must learn the value of the average
reward, whose map shows all regions.

Choices the paper leaves open (documented here and in the scenario):

- the motion is integrated exactly over a time step: x_{k+1} = r + exp(-h dt) (x_k - r). With h = 0.5 /s and
  dt = 0.5 s a robot covers 22 % of its remaining distance per step (2.2 m from 10 m away, one to two cells),
  and a leg across the area takes about 12 steps, so the grid chain mixes in tens of steps;
- arrival radius 0.5 m, half a cell: the robot reaches the waypoint's cell before it turns;
- three rectangular regions, aligned to the 1 m cells, disjoint and far apart (`PAPER_REGIONS`); a cell
  belongs to a region when its centre does.

The grid process is not Markov (the waypoint and the position inside a cell are hidden), so the reference
chain is estimated from a long simulation (`simulate_reference`, see `dgtd.problems.estimated` for why its
exact w* is the right reference).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from dgtd.errors import DgtdInputError
from dgtd.graphs.proximity import LinkStats, ProximityNetwork, count_links, empty_stats
from dgtd.problems.estimated import chain_from_counts, minibatch_td, tabular_w_star, visit_frequencies
from dgtd.samples import Block
from dgtd.scenarios.tuned import TASKS, tuned_steps
from dgtd.streams import AGENT_START, AGENT_STATE, seed_keys, uniforms

# (x0, y0, x1, y1) in metres: region i is detected only by robot i's sensor.
PAPER_REGIONS = (
    (2.0, 12.0, 7.0, 18.0),  # robot 1 (blue): a 5 m x 6 m block in the upper left
    (12.0, 13.0, 18.0, 17.0),  # robot 2 (red): a 6 m x 4 m block in the upper right
    (8.0, 2.0, 14.0, 6.0),  # robot 3 (black): a 6 m x 4 m block at the bottom centre
)


@dataclass(frozen=True)
class PatrolWorld:
    """The patrol world's parameters (SI units)."""

    size: float = 20.0
    """Side of the square area [0, size]^2, metres."""
    grid: int = 20
    """Cells per side: the grid has grid^2 states, numbered row-major from the origin (s = row * grid + col)."""
    gain: float = 0.5
    """h of the control law u = -h (x - r_i), 1/s."""
    dt: float = 0.5
    """Time between two samples (one iteration of the learner), seconds."""
    arrival_radius: float = 0.5
    """A new waypoint is drawn once the robot is this close to its waypoint, metres."""
    regions: tuple = PAPER_REGIONS
    """One rectangle (x0, y0, x1, y1) per robot: the region only that robot's sensor detects."""
    reward: float = 100.0
    """Reward to robot i while it is over region i (the paper's hat r = 100)."""
    gamma: float = 0.5
    """Discount factor (the paper's 0.5)."""

    def __post_init__(self):
        if not (self.size > 0 and self.grid >= 1 and self.gain > 0 and self.dt > 0 and self.arrival_radius > 0):
            raise DgtdInputError("size, grid, gain, dt and arrival_radius of the patrol world must all be positive")
        if len(self.regions) < 1:
            raise DgtdInputError("the patrol world needs one region per robot (at least one)")
        for x0, y0, x1, y1 in self.regions:
            if not (0 <= x0 < x1 <= self.size and 0 <= y0 < y1 <= self.size):
                raise DgtdInputError(f"region {(x0, y0, x1, y1)} must be a rectangle x0 < x1, y0 < y1 inside the area")

    @property
    def n_robots(self) -> int:
        return len(self.regions)

    @property
    def n_states(self) -> int:
        return self.grid * self.grid

    @property
    def cell(self) -> float:
        return self.size / self.grid

    @property
    def contraction(self) -> float:
        """exp(-h dt): the fraction of the distance to the waypoint left after one step."""
        return float(np.exp(-self.gain * self.dt))


def cell_index(world: PatrolWorld, x: np.ndarray) -> np.ndarray:
    """Grid state of positions x (..., 2): row-major s = row * grid + col, boundaries into the last cell."""
    ij = np.clip(np.floor(np.asarray(x) / world.cell).astype(np.int64), 0, world.grid - 1)
    return ij[..., 1] * world.grid + ij[..., 0]


def cell_centres(world: PatrolWorld) -> np.ndarray:
    """(S, 2) centre of every cell, in state order."""
    c = (np.arange(world.grid) + 0.5) * world.cell
    col, row = np.meshgrid(c, c)
    return np.stack([col.ravel(), row.ravel()], axis=1)


def region_cells(world: PatrolWorld) -> np.ndarray:
    """(N, S) bool: cell s belongs to region i when its centre lies in region i's rectangle."""
    c = cell_centres(world)
    b = np.asarray(world.regions, dtype=np.float64)
    return (
        (c[None, :, 0] >= b[:, None, 0])
        & (c[None, :, 0] <= b[:, None, 2])
        & (c[None, :, 1] >= b[:, None, 1])
        & (c[None, :, 1] <= b[:, None, 3])
    )


def reward_table(world: PatrolWorld) -> np.ndarray:
    """R (N, S): robot i earns ``reward`` in the cells of region i, zero elsewhere."""
    return world.reward * region_cells(world).astype(np.float64)


def initial(world: PatrolWorld, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start positions and first waypoints, uniform in the area, from uniforms u (..., 4)."""
    return world.size * u[..., :2], world.size * u[..., 2:4]


def move(world: PatrolWorld, x: np.ndarray, r: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One step of dt: x' = r + exp(-h dt)(x - r), the exact flow of x' = -h (x - r); then a new waypoint
    size * u (u uniforms (..., 2)) wherever the robot has arrived within ``arrival_radius``."""
    x_next = r + world.contraction * (x - r)
    gap = x_next - r
    arrived = np.einsum("...d,...d->...", gap, gap) <= world.arrival_radius**2
    return x_next, np.where(arrived[..., None], world.size * u, r)


def trajectory(world: PatrolWorld, x: np.ndarray, r: np.ndarray, U: np.ndarray):
    """Positions (T + 1, ...) from x through T steps driven by uniforms U (T, ..., 2); returns (X, r at the end)."""
    X = np.empty((U.shape[0] + 1,) + x.shape)
    X[0] = x
    for t in range(U.shape[0]):
        X[t + 1], r = move(world, X[t], r, U[t])
    return X, r


def robot_uniforms(keys: np.ndarray, steps, n: int) -> np.ndarray:
    """Robot i's uniforms of seeds ``keys`` (B,) (`dgtd.streams`): its 4 to start (``steps`` None: (B, n, 4)), or its
    2 at each of ``steps`` (T,) ((T, B, n, 2)), keyed by (seed, robot start or robot move, i, step)."""
    robots = np.arange(n)
    if steps is None:
        pairs = [uniforms(keys[:, None], AGENT_START, 0, robots, j) for j in (0, 1)]
        return np.stack([pairs[0][0], pairs[0][1], pairs[1][0], pairs[1][1]], axis=-1)
    steps = np.asarray(steps, dtype=np.uint64)[:, None, None]
    return np.stack(uniforms(keys[None, :, None], AGENT_STATE, steps, robots), axis=-1)


class PatrolSource:
    """The patrol world as a sample source for the run loop (protocol of `dgtd.sources.model.ModelSource`).

    Seed k's robots draw from its keyed streams (`robot_uniforms`): 4 uniforms per robot to start, then 2 per robot
    per step whether or not a waypoint is redrawn, each keyed by the robot and the step, so blocks of any size
    concatenate to the same run and a seed's run does not depend on the others.
    The block's ``up`` masks are the proximity links of the positions at each step, over the complete graph's
    edge list (the network's). Link statistics (how often each edge was up, how often the graph was
    connected) accumulate in ``stats``; with ``record`` > 0 the last ``record`` positions of seed 0 are kept
    at the end of every block (``snapshots``: step, trail (record, N, 2), links) for pictures.
    """

    def __init__(self, world: PatrolWorld, network: ProximityNetwork, seed: int, seed_ids, record: int = 0):
        if network.n_nodes != world.n_robots:
            raise DgtdInputError(f"the network has {network.n_nodes} agents but the world has {world.n_robots} robots")
        self.world, self.network = world, network
        self.edges = network.base.edges
        self.R = reward_table(world)
        self.seed, self.seed_ids = int(seed), np.asarray(list(seed_ids), dtype=np.int64)
        self.keys = seed_keys(self.seed, self.seed_ids)
        self.record = int(record)
        self.x: np.ndarray = np.zeros((0, 0, 2))  # positions and headings (`start` sets them)
        self.r: np.ndarray = np.zeros((0, 0))
        self.k = 0
        self.stats = empty_stats(network.n_edges)
        self.snapshots: list[tuple[int, np.ndarray, np.ndarray]] = []

    def describe(self) -> str:
        return (
            f"links between {self.world.n_robots} simulated robots whenever within {self.network.radius:g} m, "
            "recomputed at every step"
        )

    def start(self) -> None:
        N = self.world.n_robots
        self.x, self.r = initial(self.world, robot_uniforms(self.keys, None, N))
        self.k = 0
        self.stats = empty_stats(self.network.n_edges)
        self.snapshots = []
        if self.record:
            self.snapshots.append((0, self.x[0][None].copy(), self.network.masks(self.x[0])))

    def next_block(self, T: int) -> Block:
        N = self.world.n_robots
        U = robot_uniforms(self.keys, self.k + np.arange(T), N)  # (T, B, N, 2)
        X, self.r = trajectory(self.world, self.x, self.r, U)
        self.x = X[-1].copy()
        cells = cell_index(self.world, X)  # (T + 1, B, N)
        s, s_next = cells[:-1], cells[1:]
        up = self.network.masks(X[:-1])  # the graph at step k is set by the positions at step k
        self.stats = count_links(self.stats, up, self.edges, N)
        self.k += T
        if self.record:
            self.snapshots.append((self.k, X[-self.record :, 0].copy(), self.network.masks(X[-1, 0])))
        r = self.R[np.arange(N), s]  # agent i's reward at its own cell
        return Block(s, np.zeros_like(s), np.ascontiguousarray(s_next), r, up)

    def get_state(self) -> dict:
        return {
            "x": self.x.copy(),
            "r": self.r.copy(),
            "k": self.k,
            "stats": self.stats,
        }

    def set_state(self, state: dict) -> None:
        self.x, self.r, self.k, self.stats = state["x"].copy(), state["r"].copy(), state["k"], state["stats"]


@dataclass(frozen=True, eq=False)
class ReferenceChain:
    """The grid chain estimated from a long simulation, and what it says about its own accuracy.

    - ``counts`` (S, S) transitions s -> s' counted over all robots after the burn-in; ``P`` = row-normalised.
    - ``visits`` (S,) visit frequencies; ``d`` (S,) the exact stationary distribution of ``P``.
    - ``w_star`` (S,) exact tabular w* of the estimated chain for the average reward.
    - ``w_replicates`` (K, S): w* of the chains estimated from K disjoint groups of teams; their spread gives the
      standard error of ``w_star`` (``w_star_stderr``, sup over states).
    - ``w_td`` (S,): centralised TD(0) on the same samples (`minibatch_td`), a cross-check of ``w_star``.
    - ``links``: proximity-link statistics of teams of N robots, giving the mean graph.
    """

    world: PatrolWorld
    teams: int
    steps: int
    burn_in: int
    seed: int
    counts: np.ndarray
    P: np.ndarray
    visits: np.ndarray
    d: np.ndarray
    w_star: np.ndarray
    w_replicates: np.ndarray
    w_td: np.ndarray
    links: LinkStats

    @property
    def n_transitions(self) -> int:
        return int(self.counts.sum())

    @property
    def w_star_stderr(self) -> float:
        K = self.w_replicates.shape[0]
        return float((self.w_replicates.std(axis=0, ddof=1) / np.sqrt(K)).max()) if K > 1 else float("nan")

    def summary(self) -> dict:
        scale = float(np.abs(self.w_star).max())
        return {
            "teams": self.teams,
            "robots": self.teams * self.world.n_robots,
            "steps": self.steps,
            "burn_in": self.burn_in,
            "seed": self.seed,
            "transitions": self.n_transitions,
            "min_visits": int(self.counts.sum(axis=1).min()),
            "w_star_stderr_relative": self.w_star_stderr / scale,
            "td_vs_w_star_relative": float(np.abs(self.w_td - self.w_star).max()) / scale,
            "stationary_vs_visits_max_abs": float(np.abs(self.d - self.visits).max()),
            "link_frequency": self.links.link_frequency.tolist(),
            "connected_fraction": self.links.connected_fraction,
        }


def simulate_reference(
    world: PatrolWorld,
    network: ProximityNetwork,
    teams: int,
    steps: int,
    burn_in: int = 200,
    seed: int = 0,
    replicates: int = 4,
    block: int = 256,
    omega: float = 0.85,
) -> ReferenceChain:
    """Simulate ``teams`` independent teams of N robots for burn_in + steps steps and estimate the grid chain.

    All robots are independent copies of one chain, so their transitions are pooled; teams only matter for the
    proximity links. Teams start uniform and run ``burn_in`` uncounted steps (a few legs, so the start is
    forgotten). The randomness is the keyed streams of seed 0 of ``seed``, robot i of team m its entity m N + i.
    """
    from dgtd.problems.exact import stationary_distribution

    teams, steps, burn_in, replicates = int(teams), int(steps), int(burn_in), int(replicates)
    if teams < replicates or steps < 1 or burn_in < 0 or replicates < 1:
        raise DgtdInputError("the reference run needs steps >= 1, burn_in >= 0 and at least one team per replicate")
    N, S = world.n_robots, world.n_states
    key = seed_keys(int(seed), [0])
    x, r = initial(world, robot_uniforms(key, None, teams * N).reshape(teams, N, 4))
    group = (np.arange(teams) * replicates // teams)[:, None] * np.ones(N, np.int64)  # (teams, N) replicate id
    counts = np.zeros(replicates * S * S, np.int64)
    r_mean = reward_table(world).mean(axis=0)
    w_td, n_seen = np.zeros(S), np.zeros(S, np.int64)
    links = empty_stats(network.n_edges)
    done = -burn_in
    # A few seconds before any run starts: said on a terminal, so that the wait is not silent.
    bar = tqdm(
        total=burn_in + steps,
        desc=f"simulating the reference map ({teams} teams)",
        unit="step",
        disable=None,
        file=sys.stderr,
        leave=False,
        mininterval=0.5,
    )
    while done < steps:
        T = min(block, steps - done) if done >= 0 else min(block, -done)
        u = robot_uniforms(key, burn_in + done + np.arange(T), teams * N).reshape(T, teams, N, 2)
        X, r = trajectory(world, x, r, u)
        x = X[-1]
        if done >= 0:
            cells = cell_index(world, X)
            s, s_next = cells[:-1], cells[1:]
            counts += np.bincount(((group * S + s) * S + s_next).ravel(), minlength=replicates * S * S)
            links = count_links(links, network.masks(X[:-1]), network.base.edges, N)
            for t in range(T):
                w_td, n_seen = minibatch_td(w_td, n_seen, s[t].ravel(), s_next[t].ravel(), r_mean, world.gamma, omega)
        done += T
        bar.update(T)
    bar.close()
    per_group = counts.reshape(replicates, S, S)
    total = per_group.sum(axis=0)
    P = chain_from_counts(total)
    w_rep = (
        np.stack([tabular_w_star(chain_from_counts(c), r_mean, world.gamma) for c in per_group])
        if replicates > 1
        else np.zeros((0, S))
    )
    return ReferenceChain(
        world,
        teams,
        steps,
        burn_in,
        int(seed),
        total,
        P,
        visit_frequencies(total),
        stationary_distribution(P),
        tabular_w_star(P, r_mean, world.gamma),
        w_rep,
        w_td,
        links,
    )


def map_correlation(W: np.ndarray, w_ref: np.ndarray) -> np.ndarray:
    """Pearson correlation of each map W (..., S) with the reference map (S,), shape (...)."""
    a = W - W.mean(axis=-1, keepdims=True)
    b = w_ref - w_ref.mean()
    return (a @ b) / np.maximum(np.linalg.norm(a, axis=-1) * np.linalg.norm(b), 1e-300)


@dataclass(frozen=True, eq=False)
class PatrolReport:
    """After a run: the numbers summary.json records for the patrol world (its figures: `dgtd.plots.robots`).

    Called as ``report(result, source) -> (dict, text)``; ``source`` is the run's `PatrolSource`.
    """

    world: PatrolWorld
    network: ProximityNetwork
    reference: ReferenceChain

    def numbers(self, result, source: PatrolSource) -> dict:
        from dataclasses import asdict

        from dgtd.problems import exact

        d = self.reference.d
        err_d = np.sqrt((d * (result.w_last - result.w_star) ** 2).sum(-1) / (d * result.w_star**2).sum())
        return {
            "world": asdict(self.world),
            "communication_radius": self.network.radius,
            "reference": self.reference.summary(),
            "links_during_run": source.stats.as_dict(self.network.base),
            "correlation_last": map_correlation(result.w_last, result.w_star).tolist(),
            "correlation_tail": map_correlation(result.w_tail, result.w_star).tolist(),
            "relative_error_d_weighted_last": err_d.tolist(),  # |w_i - w*|_D / |w*|_D
            "consensus_last": exact.consensus_error(result.w_last).tolist(),
            # sqrt(sum_i |w_i - mean w|^2 / N) / |w*|_2: the agents' typical distance from their mean, relative
            "consensus_relative_last": (
                np.sqrt(exact.consensus_error(result.w_last) / result.w_last.shape[1]) / np.linalg.norm(result.w_star)
            ).tolist(),
            "w_td_reference": self.reference.w_td.tolist(),
        }

    def arrays(self, source: PatrolSource) -> dict:
        """What the figures need of the run beyond its numbers, for scenario.npz: the recorded steps, seed 0's
        trails (K, record, N, 2; shorter trails padded with NaN in front) and the links up (K, E) at each."""
        snaps = source.snapshots
        longest = max((len(trail) for _, trail, _ in snaps), default=0)
        trails = np.full((len(snaps), longest, self.world.n_robots, 2), np.nan)
        for j, (_, trail, _) in enumerate(snaps):
            trails[j, longest - len(trail) :] = trail
        return {
            "snapshot_steps": np.array([k for k, _, _ in snaps], dtype=np.int64),
            "snapshot_trails": trails,
            "snapshot_links": np.array([up for _, _, up in snaps], dtype=bool).reshape(len(snaps), -1),
        }

    @staticmethod
    def saved(arrays: dict):
        """A stand-in for the run's source with its ``snapshots`` as `arrays` saved them (for `dgtd plot`)."""
        from types import SimpleNamespace

        trails = arrays["snapshot_trails"]
        snaps = [
            (int(k), trail[~np.isnan(trail).any(axis=(1, 2))], up)
            for k, trail, up in zip(arrays["snapshot_steps"], trails, arrays["snapshot_links"])
        ]
        return SimpleNamespace(snapshots=snaps)

    def __call__(self, result, source: PatrolSource) -> tuple[dict, str]:
        info = self.numbers(result, source)
        corr = np.asarray(info["correlation_last"])
        links = info["links_during_run"]
        text = (
            f"correlation of each agent's map with the reference (seed 0): "
            f"{', '.join(f'agent {i + 1} {c:.4f}' for i, c in enumerate(corr[0]))}; worst over seeds {corr.min():.4f}\n"
            f"final consensus error (seed 0) {info['consensus_last'][0]:.3g}: each agent's RMS distance from the "
            f"agents' mean is {info['consensus_relative_last'][0]:.2%} of |w*|_2; D-weighted error |w_i - w*|_D / "
            f"|w*|_D at most {max(info['relative_error_d_weighted_last'][0]):.2%}\n"
            f"network during the run: connected at {links['connected_fraction']:.1%} of steps, link frequencies "
            f"{', '.join(f'{p:.3f}' for p in links['link_frequency'])}; reference chain from "
            f"{info['reference']['transitions']:,} transitions (w* standard error "
            f"{info['reference']['w_star_stderr_relative']:.2%} of max |w*|, TD cross-check "
            f"{info['reference']['td_vs_w_star_relative']:.2%})"
        )
        return info, text


def patrol_scenario(
    world: PatrolWorld = PatrolWorld(),
    radius: float = 5.0,
    *,
    algorithm,
    iterations: int,
    name: str,
    description: str,
    reference_teams: int = 400,
    reference_steps: int = 10_000,
    reference_burn_in: int = 200,
    reference_seed: int = 0,
    record: int = 25,
):
    """A `Scenario` for a patrol world: the estimated grid chain as the problem, the mean proximity graph as
    the network (for mu* and the connectivity check), and a `PatrolSource` factory for the actual samples."""
    from functools import partial

    from dgtd.problems.features import tabular
    from dgtd.problems.model import make_problem
    from dgtd.scenarios.base import Scenario
    from dgtd.sources.model import Sampling

    proximity = ProximityNetwork(world.n_robots, radius)
    ref = simulate_reference(world, proximity, reference_teams, reference_steps, reference_burn_in, reference_seed)
    problem = make_problem(ref.P, reward_table(world), tabular(world.n_states), world.gamma, name=name)
    return Scenario(
        problem=problem,
        network=ref.links.mean_network(proximity.base),
        algorithm=algorithm,
        sampling=Sampling(mode="markov", shared=False),
        iterations=int(iterations),
        description=description,
        source=partial(PatrolSource, world, proximity, record=record),
        report=PatrolReport(world, proximity, ref),
        compare_settings=tuned_steps(name) if name in TASKS else {},
    )
