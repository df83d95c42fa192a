"""A run described as plain data (`RunSpec`) and its resolution into library objects.

Every field may be left None to take the scenario's value; `resolve` returns the objects and the fully
resolved spec, which is what results directories record so that a run can be reproduced exactly.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

from dgtd.algorithms.dgtd import DGTD
from dgtd.errors import DgtdInputError
from dgtd.graphs import topologies
from dgtd.graphs.random import random_edges
from dgtd.problems.io import file_digest, load_problem
from dgtd.problems.scenarios import get_scenario
from dgtd.run.loop import RunSettings
from dgtd.run.sampling import Sampling


@dataclass(frozen=True)
class RunSpec:
    """One run of Algorithm 1, as data. ``scenario`` or ``problem_file`` names the problem."""

    scenario: str | None = None
    problem_file: str | None = None
    graph: str | None = None
    edge_prob: float | None = None
    iterations: int | None = None
    seeds: int = 1
    seed: int = 0
    alpha0: float | None = None
    beta: float | None = None
    schedule: str | None = None
    kappa: float | None = None
    rho: float | None = None
    sampling: str | None = None
    shared: bool | None = None
    reward_noise: str | None = None
    backend: str = "numba"
    checkpoints: int = 200
    tail_fraction: float = 0.5
    block_size: int = 4096

    def to_dict(self) -> dict:
        return asdict(self)


def _network(graph: str, n_agents: int, edge_prob: float):
    if graph in topologies.TOPOLOGIES:
        base = topologies.TOPOLOGIES[graph](n_agents)
    else:
        base = topologies.read_edge_list(graph)
        if base.n_nodes > n_agents:
            raise DgtdInputError(f"edge list {graph} names agent {base.n_nodes - 1} but the problem has {n_agents} agents")
        base = topologies.from_edges(n_agents, base.edges, base.name)
    return random_edges(base, edge_prob)


def resolve(spec: RunSpec):
    """(problem, network, algorithm, sampling, settings, resolved spec) for a spec."""
    if (spec.scenario is None) == (spec.problem_file is None):
        raise DgtdInputError("name exactly one problem: a scenario (e.g. paper-example-1) or --problem FILE.npz")
    if spec.scenario is not None:
        sc = get_scenario(spec.scenario, **({} if spec.edge_prob is None else {"edge_prob": spec.edge_prob}))
        problem, network, algorithm, sampling, iterations = sc.problem, sc.network, sc.algorithm, sc.sampling, sc.iterations
        graph, edge_prob = sc.network.base.name, float(sc.network.p.max())
        if sc.source is not None:
            _refuse_model_overrides(spec, sc)
            graph, edge_prob = None, None  # the scenario's source sets the links; nothing to record
        if spec.reward_noise not in (None, problem.reward_noise):
            problem = replace(problem, reward_noise=spec.reward_noise)
    else:
        problem = load_problem(spec.problem_file, reward_noise=spec.reward_noise or "none")
        graph, edge_prob, iterations = "ring", 1.0, 100_000
        algorithm, sampling, network = DGTD(), Sampling(), None
    if spec.graph is not None or network is None:
        graph = spec.graph or graph
        edge_prob = spec.edge_prob if spec.edge_prob is not None else edge_prob
        network = _network(graph, problem.n_agents, edge_prob)
    over = {k: getattr(spec, k) for k in ("alpha0", "beta", "schedule", "kappa", "rho") if getattr(spec, k) is not None}
    algorithm = replace(algorithm, **over)
    sampling = Sampling(mode=spec.sampling or sampling.mode, shared=sampling.shared if spec.shared is None else spec.shared)
    settings = RunSettings(
        iterations=int(iterations if spec.iterations is None else spec.iterations), seeds=spec.seeds, seed=spec.seed, checkpoints=spec.checkpoints,
        tail_fraction=spec.tail_fraction, block_size=spec.block_size, backend=spec.backend,
    )
    resolved = replace(
        spec, graph=graph, edge_prob=edge_prob, iterations=settings.iterations, alpha0=algorithm.alpha0,
        beta=algorithm.beta, schedule=algorithm.schedule, kappa=algorithm.kappa, rho=algorithm.rho,
        sampling=sampling.mode, shared=sampling.shared, reward_noise=problem.reward_noise,
    )
    return problem, network, algorithm, sampling, settings, resolved


def _refuse_model_overrides(spec: RunSpec, sc) -> None:
    """A scenario with its own sample source sets the links, states and rewards itself: flags that would change
    them could not apply, so they are refused (values equal to the scenario's own, as recorded, are accepted)."""
    own = {"--graph": None, "--sampling": sc.sampling.mode, "--shared": sc.sampling.shared,
           "--reward-noise": sc.problem.reward_noise}
    given = [flag for flag, value in (("--graph", spec.graph), ("--sampling", spec.sampling), ("--shared", spec.shared),
                                      ("--reward-noise", spec.reward_noise)) if value is not None and value != own[flag]]
    if given:
        raise DgtdInputError(f"scenario {spec.scenario} simulates its own samples and links; {', '.join(given)} "
                             f"{'does' if len(given) == 1 else 'do'} not apply to it (leave {'it' if len(given) == 1 else 'them'} out)")


def scenario_of(spec: RunSpec):
    """The named `Scenario` of a spec (cached by its builder where building is costly), or None for a problem file."""
    return None if spec.scenario is None else get_scenario(spec.scenario)


def make_source(spec: RunSpec, settings: RunSettings):
    """A fresh sample source for a run of ``spec``, or None when samples come from the model (`ModelSource`).

    Scenarios that simulate a world (e.g. paper-example-2's robots and their proximity links) supply their own;
    pass it as ``run(..., source=make_source(spec, settings))``. Each call starts the same streams again, so
    two algorithms given fresh sources with one seed see identical samples and links.
    """
    sc = scenario_of(spec)
    if sc is None or sc.source is None:
        return None
    return sc.source(settings.seed, range(settings.seeds))


def spec_record(spec: RunSpec) -> dict:
    """The resolved spec as JSON-ready data, with the problem file's SHA-256 when there is one."""
    d = spec.to_dict()
    if spec.problem_file is not None:
        d["problem_sha256"] = file_digest(spec.problem_file)
    return d
