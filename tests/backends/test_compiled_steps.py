"""Every algorithm of the registry through both backends: the compiled driver with each algorithm's per-agent step
gives the NumPy reference's numbers (to 1e-9: the same samples and the same arithmetic, summed in other orders), in
both layouts, with dense and sparse features, on a model's samples and on recorded ones, continuing and episodic; and
the layouts give each other's numbers to the last bit."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from helpers import agent_layout_param
from numpy.testing import assert_array_equal

from dgtd.algorithms import ALGORITHMS, make_algorithm
from dgtd.backends.compiled import STEPS
from dgtd.graphs import topologies
from dgtd.graphs.random import random_edges
from dgtd.problems import tasks
from dgtd.problems.generators import random_mdp_problem, random_problem
from dgtd.run.loop import RunSettings, run
from dgtd.sources.model import Sampling

SENDING = [name for name in ALGORITHMS if ALGORITHMS[name].messages]
SENDING_LAYOUTS = [agent_layout_param(name) for name in SENDING]  # the agent layout: some slow


def model_case(problem, sampling=Sampling(), edge_prob=0.6):
    return problem, random_edges(topologies.ring_with_chords(problem.n_agents, 2), edge_prob), sampling, None


def recorded_case(tmp_path_factory):
    """Recordings of a Garnet chain's transitions (their own features, ratios and flags: a table per block), over a
    ring whose links are up with probability 0.6."""
    from helpers import record

    from dgtd.sources.data import DataSource, TransitionFile

    problem = tasks.garnet(n_states=8, branching=3, n_agents=4, n_features=3, gamma=0.8, seed=1)
    path = tmp_path_factory.mktemp("recorded") / "t.npz"
    np.savez(path, **record(problem, seeds=2, steps=400))
    data = TransitionFile(path)
    network = random_edges(topologies.ring(4), 0.6)
    return data.reference(problem.gamma), network, Sampling("markov"), lambda: DataSource(data, [0, 1], 11, network)


CASES = {
    "iid-noise": lambda f: model_case(random_problem(6, 5, 4, np.random.default_rng(3), reward_noise="bernoulli")),
    "markov-shared-fixed": lambda f: model_case(
        random_problem(6, 5, 4, np.random.default_rng(4)), Sampling("markov", True), 1.0
    ),
    "off-policy": lambda f: model_case(
        random_mdp_problem(5, (2, 2, 1, 2, 2), 4, np.random.default_rng(5), off_policy=True), Sampling("markov")
    ),
    "sparse-tabular": lambda f: model_case(random_problem(9, 5, 9, np.random.default_rng(6))),
    "episodic": lambda f: model_case(tasks.boyan(n_agents=5, n_states=8), Sampling("markov")),
    "recorded": recorded_case,
}


@pytest.fixture(scope="module")
def cases(tmp_path_factory):
    return {name: make(tmp_path_factory) for name, make in CASES.items()}


def both(case, name, layout, monkeypatch, T=300, block=97):
    """The reference's run and the compiled one of ``name`` in ``layout`` on ``case`` (blocks of an odd length, so
    that a block ends on either message buffer)."""
    from dgtd.backends.compiled import driver

    problem, network, sampling, source = case
    monkeypatch.setattr(driver, "LAYOUT", layout)
    algorithm = make_algorithm(name, alpha0=0.05, beta=10.0)
    settings = RunSettings(iterations=T, seeds=2, seed=11, checkpoints=4, block_size=block)
    out = {}
    for backend in ("numpy", "numba"):
        out[backend] = run(
            problem,
            network,
            algorithm,
            sampling,
            dataclasses.replace(settings, backend=backend),
            source=None if source is None else source(),
        )
    return out["numpy"], out["numba"]


def test_every_algorithm_has_a_compiled_step():
    assert set(STEPS) == set(ALGORITHMS)


@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.parametrize("name", sorted(ALGORITHMS))
def test_the_compiled_step_gives_the_reference_numbers(name, case, cases, monkeypatch):
    from helpers import assert_same_run

    ref, fast = both(cases[case], name, "seeds", monkeypatch)
    assert np.all(ref.info["diverged_at"] < 0)
    assert_same_run(ref, fast, 1e-9, 1e-12)


@pytest.mark.parametrize("case", ["iid-noise", "sparse-tabular", "recorded"])
@pytest.mark.parametrize("name", SENDING_LAYOUTS)
def test_the_agent_layout_gives_the_seed_layouts_numbers_bit_for_bit(name, case, cases, monkeypatch):
    """The agents of a seed spread over the cores, their samples drawn a step ahead: the same numbers to the bit."""
    _, seeds = both(cases[case], name, "seeds", monkeypatch)
    ref, agents = both(cases[case], name, "agents", monkeypatch)
    for key in seeds.final_state:
        assert_array_equal(agents.final_state[key], seeds.final_state[key])
    assert_array_equal(agents.w_avg, seeds.w_avg)
    assert_array_equal(agents.info["counts"]["messages"], ref.info["counts"]["messages"])
