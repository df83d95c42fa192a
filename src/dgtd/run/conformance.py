"""`check_algorithm`: the conformance check every algorithm of dgtd passes, offered for a user's own (as PettingZoo's
``parallel_api_test`` is for environments).

An algorithm written in the one definition of `dgtd.algorithms.base` runs on every backend from its class alone; this
checks that it does, and that the backends agree, on small problems that cover what a run meets: a model's i.i.d.
samples with noisy rewards, a Markov trajectory off-policy, tabular (sparse) features on one shared trajectory, an
episodic task, and recorded samples that carry their own features (a table per block), each over a random ring with
chords whose links are up with probability 0.6.
"""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np

from dgtd.algorithms.base import check_contract
from dgtd.errors import DgtdInputError
from dgtd.graphs import topologies
from dgtd.graphs.random import random_edges
from dgtd.problems import tasks
from dgtd.problems.generators import random_mdp_problem, random_problem
from dgtd.run.loop import RunSettings, run
from dgtd.samples import Block, SampleTable
from dgtd.sources.model import ModelSource, Sampling

ITERATIONS = 300  # steps of each run, in blocks of 97 (so that a block ends on either message buffer)
# relative differences allowed against the reference: the same arithmetic, summed in other orders
TOLERANCE = {"numba": 1e-9, "jax": 1e-12}


class Recorded:
    """A model's samples handed over as recorded ones are: each block with its own table of features, ratios and
    flags (`dgtd.samples.SampleTable`), the path of `dgtd.sources.data.DataSource` (on-policy, so every ratio is 1)."""

    def __init__(self, model: ModelSource):
        self.model, p = model, model.problem
        self.table = SampleTable(p.Phi, np.ones((p.n_states, 1)), np.ones(p.n_states))

    def start(self) -> None:
        self.model.start()

    def next_block(self, T: int) -> Block:
        blk = self.model.next_block(T)
        return blk._replace(a=np.zeros_like(blk.a), table=self.table)

    def get_state(self) -> dict:
        return self.model.get_state()

    def set_state(self, state: dict) -> None:
        self.model.set_state(state)


def _cases() -> dict:
    return {
        "iid-noise": (random_problem(6, 5, 4, np.random.default_rng(3), reward_noise="bernoulli"), Sampling()),
        "markov-off-policy": (
            random_mdp_problem(5, (2, 2, 1, 2, 2), 4, np.random.default_rng(5), off_policy=True),
            Sampling("markov"),
        ),
        "tabular-shared": (random_problem(9, 5, 9, np.random.default_rng(6)), Sampling("markov", True)),
        "episodic": (tasks.boyan(n_agents=5, n_states=8), Sampling("markov")),
        "recorded": (random_problem(6, 5, 4, np.random.default_rng(7)), Sampling()),
    }


def check_algorithm(algorithm, backends: tuple[str, ...] | None = None) -> dict:
    """Run ``algorithm`` (an instance) on every case above on every backend it can run on, and raise AssertionError,
    saying which case, backend and quantity, where one differs from the NumPy reference by more than `TOLERANCE`
    (final state, averaged iterates, every metric; message counts exactly) or where the compiled layouts (seeds one
    after another, agents spread over the cores) differ at all. ``backends``: those to compare with the reference
    (default: numba, and jax where JAX is installed). Returns {case: {backend: largest relative difference}}.

    Example::

        >>> import dgtd
        >>> report = dgtd.check_algorithm(dgtd.TD0(alpha0=0.05))  # doctest: +SKIP
    """
    from dgtd.backends import jax as on_jax
    from dgtd.backends.compiled import step_of

    _check_shape(algorithm)
    if backends is None:
        backends = ("numba",) + (("jax",) if on_jax.available() else ())
    if "numba" in backends and step_of(algorithm) is None:
        raise AssertionError(
            f"{algorithm.name} writes update alone: the compiled backend cannot run it (write its arithmetic in the "
            "one definition of dgtd.algorithms.base)"
        )
    report: dict = {}
    for case, (problem, sampling) in _cases().items():
        reference = _run(algorithm, case, problem, sampling, "numpy")
        report[case] = {}
        for backend in backends:
            result = _run(algorithm, case, problem, sampling, backend, "seeds")
            report[case][backend] = _compare(reference, result, TOLERANCE[backend], f"{case}, {backend}")
            if backend == "numba" and algorithm.messages:
                agents = _run(algorithm, case, problem, sampling, backend, "agents")
                _compare(result, agents, 0.0, f"{case}, numba's agent layout against its seed layout")
    return report


FINDING = 400  # characters of a user's exception kept in a finding's one line


def finding(algorithm, where: str, error: Exception) -> AssertionError:
    """What a user's algorithm raised ``where``, as a finding of one line: its name, the case and backend, the
    exception's type and its first lines (numba's typing errors run to pages; ``--debug``'s traceback keeps it all)."""
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    text = " ".join(lines[:3]) or "(no message)"
    text = text if len(text) <= FINDING else text[: FINDING - 3] + "..."
    return AssertionError(
        f"{getattr(algorithm, 'name', type(algorithm).__name__)}, {where}: {type(error).__name__}: {text}"
    )


def _run(algorithm, case: str, problem, sampling, backend: str, layout: str = "auto"):
    """300 steps of 2 seeds of ``algorithm`` on ``problem`` over a ring with chords whose links are up with
    probability 0.6, on ``backend`` (numba's in ``layout``); recorded samples for the case "recorded". What the
    algorithm's code raises is a `finding`."""
    try:
        return _run_case(algorithm, case, problem, sampling, backend, layout)
    except (AssertionError, KeyboardInterrupt):
        raise
    except Exception as e:  # noqa: BLE001  (the user's algorithm failing: theirs to see, in one line)
        raise finding(algorithm, f"case {case} on {backend}", e) from e


def _run_case(algorithm, case: str, problem, sampling, backend: str, layout: str):
    from dgtd.run.loop import prepare

    network = random_edges(topologies.ring_with_chords(problem.n_agents, 2), 0.6)
    settings = RunSettings(iterations=ITERATIONS, seeds=2, seed=11, checkpoints=4, block_size=97, backend=backend)
    source = None
    if case == "recorded":
        tables = prepare(problem, network, algorithm, sampling, settings)[0].tables
        source = Recorded(ModelSource(problem, network, sampling, tables, settings.seed, range(settings.seeds)))
    with _layout(layout):
        return run(problem, network, algorithm, sampling, settings, source=source)


def _check_shape(algorithm) -> None:
    """What the run loop and the backends rely on: a NamedTuple state (B, N or 1, q) whose fields list what an agent
    keeps before what it sends, messages named by ``sends`` as by ``messages``, an ``update`` that leaves its input."""
    try:
        check_contract(algorithm)
    except DgtdInputError as e:
        raise AssertionError(str(e)) from None
    except Exception as e:  # noqa: BLE001  (its init or sends failing)
        raise finding(algorithm, "its contract (init(2, 3, 4) and sends)", e) from e


def _compare(ref, got, rtol: float, what: str) -> float:
    scale = max(1.0, float(np.abs(ref.w_last).max()))
    worst = 0.0
    pairs = [(f"final {k}", ref.final_state[k], got.final_state[k]) for k in ref.final_state]
    pairs += [("averaged iterates", ref.w_avg, got.w_avg)] + [(k, ref.metrics[k], got.metrics[k]) for k in ref.metrics]
    for name, a, b in pairs:
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        same_nan = np.isnan(a) == np.isnan(b)
        diff = np.where(np.isnan(a) & np.isnan(b), 0.0, np.abs(a - b)) / scale
        worst = max(worst, float(np.nanmax(diff, initial=0.0)))
        if not (same_nan.all() and np.all(diff <= rtol * np.maximum(1.0, np.abs(a) / scale) + (rtol and 1e-14))):
            raise AssertionError(f"{what}: {name} differs from the reference by {float(np.nanmax(diff)):.3g} x scale")
    for key in ref.info["counts"]:
        if not np.array_equal(ref.info["counts"][key], got.info["counts"][key]):
            raise AssertionError(f"{what}: the counts of {key} differ")
    return worst


@contextmanager
def _layout(layout: str):
    from dgtd.backends.compiled import driver

    before, driver.LAYOUT = driver.LAYOUT, layout
    try:
        yield
    finally:
        driver.LAYOUT = before
