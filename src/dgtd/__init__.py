"""dgtd: distributed policy evaluation with the primal-dual distributed GTD method and its baselines.

The names a user needs, each documented where it is defined::

    import dgtd

    sc = dgtd.scenario("paper-example-1")                     # a named, ready-to-run setting
    result = dgtd.evaluate(sc.problem, sc.network, dgtd.DGTD(alpha0=1.0), iterations=100_000, seeds=4)
    result.metrics["error_avg"][-1]                           # max_i |w_i - w*| / |w*| per seed, averaged iterate

- one run configuration: `RunConfig` and its sections `ProblemConfig`, `NetworkConfig`, `AlgorithmConfig`,
  `SamplingConfig`, `RunLength`, `Output` (what an experiment file holds), and `execute`, which runs one as
  ``dgtd run`` does;
- runs: `evaluate` (`dgtd.run.loop.run` is the loop itself, with checkpoints and resume), `RunSettings`,
  `Sampling`, `RunResult`;
- scenarios: `scenario`, `SCENARIOS`;
- algorithms: `DGTD`, `GTD2`, `TDC`, `TDRC`, `TD0`, `ConsensusTD0`, `PDTD`, `TDTracking`, `TDCTracking`,
  `ConsensusTDRC`, `Local`, `make_algorithm`,
  `ALGORITHMS`, and `check_algorithm`, which checks a user's own on every backend;
- problems: `make_problem`, `from_mdp`, `load_problem`, `save_problem`, `tasks`, `exact`;
- graphs: `ring`, `path`, `star`, `complete`, `from_edges`, `from_networkx`, `random_edges`;
- channels, which turn what agents send into what they hear: `Perfect`, `Lossy`, `Imperfect`, `Inbox`, `Arcs`,
  `Channel`, the protocol a link model of one's own follows, and `check_channel`, which checks one;
- results: `read_results`;
- agents that learn their policies: `learn` (the networked actor-critic with any distributed critic),
  `LearnSettings`, `SoftmaxActor`, and `team_mdp` / `TeamMDP`, the multi-agent MDPs they learn on.

Names load on first use, so ``import dgtd`` stays quick (the compiled kernels load only when a run needs them).
"""

import importlib as _importlib
import os as _os

# When agents are spread over the cores, the compiled kernels synchronise their threads at every step. Threads
# that go to sleep at once pay two wake-ups per step (measured on a 2-core virtual machine: about 0.1 ms per step,
# half the run time with a few hundred agents); OpenMP's default spin of a few milliseconds stalls every step on a
# core shared with another busy process (seen: 10x slower). A short spin keeps the fast hand-over between steps
# and bounds what a shared core loses (there: about 25 % slower than not spinning). Values the user set are kept.
if "OMP_WAIT_POLICY" not in _os.environ and "GOMP_SPINCOUNT" not in _os.environ:
    _os.environ["GOMP_SPINCOUNT"] = "10000"
# A rank of an mpiexec job shares this machine's cores with the job's other ranks here (MPI_LOCALNRANKS, which MPICH
# sets; OMPI_COMM_WORLD_LOCAL_SIZE, Open MPI): each gets its share of BLAS threads and of the compiled kernels'
# threads, set before NumPy and numba load, or their threads fight over the cores (measured: the exact solution of
# 30 000 agents took 41.5 s on each of 2 ranks, 1.6 s with one thread each). Values the user set are kept.
_local = _os.environ.get("MPI_LOCALNRANKS") or _os.environ.get("OMPI_COMM_WORLD_LOCAL_SIZE")
if _local:
    _share = str(max(1, (_os.cpu_count() or 1) // max(1, int(_local))))
    if "OPENBLAS_NUM_THREADS" not in _os.environ and "OMP_NUM_THREADS" not in _os.environ:
        _os.environ["OPENBLAS_NUM_THREADS"] = _share
    _os.environ.setdefault("NUMBA_NUM_THREADS", _share)

__version__ = "0.1.0"

_EXPORTS = {
    "evaluate": "dgtd.run.loop",
    "execute": "dgtd.cli.job",
    "RunConfig": "dgtd.config",
    "ProblemConfig": "dgtd.config",
    "NetworkConfig": "dgtd.config",
    "AlgorithmConfig": "dgtd.config",
    "SamplingConfig": "dgtd.config",
    "RunLength": "dgtd.config",
    "Output": "dgtd.config",
    "RunSettings": "dgtd.run.loop",
    "RunResult": "dgtd.run.loop",
    "Sampling": "dgtd.sources.model",
    "scenario": ("dgtd.scenarios", "get_scenario"),
    "SCENARIOS": "dgtd.scenarios",
    "DGTD": "dgtd.algorithms",
    "GTD2": "dgtd.algorithms",
    "TDC": "dgtd.algorithms",
    "TDRC": "dgtd.algorithms",
    "TDCTracking": "dgtd.algorithms",
    "ConsensusTDRC": "dgtd.algorithms",
    "TD0": "dgtd.algorithms",
    "ConsensusTD0": "dgtd.algorithms",
    "PDTD": "dgtd.algorithms",
    "TDTracking": "dgtd.algorithms",
    "Local": "dgtd.algorithms",
    "make_algorithm": "dgtd.algorithms",
    "ALGORITHMS": "dgtd.algorithms",
    "make_problem": "dgtd.problems.model",
    "from_mdp": "dgtd.problems.mdp",
    "load_problem": "dgtd.problems.io",
    "save_problem": "dgtd.problems.io",
    "tasks": ("dgtd.problems", "tasks"),
    "exact": ("dgtd.problems", "exact"),
    "ring": "dgtd.graphs.topologies",
    "path": "dgtd.graphs.topologies",
    "star": "dgtd.graphs.topologies",
    "complete": "dgtd.graphs.topologies",
    "from_edges": "dgtd.graphs.topologies",
    "from_networkx": "dgtd.graphs.topologies",
    "random_edges": "dgtd.graphs.random",
    "Perfect": "dgtd.channels",
    "Lossy": "dgtd.channels",
    "Imperfect": "dgtd.channels",
    "Channel": "dgtd.channels",
    "Inbox": "dgtd.channels",
    "Arcs": "dgtd.channels",
    "read_results": "dgtd.run.results",
    "check_algorithm": "dgtd.run.conformance",
    "check_channel": "dgtd.run.channel_check",
    "learn": "dgtd.run.learn",
    "LearnSettings": "dgtd.run.learn",
    "SoftmaxActor": "dgtd.algorithms.actor",
    "team_mdp": "dgtd.problems.team",
    "TeamMDP": "dgtd.problems.team",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name not in _EXPORTS:
        raise AttributeError(f"module 'dgtd' has no attribute {name!r}")
    where = _EXPORTS[name]
    module, attr = where if isinstance(where, tuple) else (where, name)
    value = getattr(_importlib.import_module(module), attr)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_EXPORTS))
