"""The JAX backend runs every algorithm's one definition and gives the NumPy reference's numbers on the same samples
from the same seed, to 1e-12 in float64 (measured: 1e-15; the same arithmetic, its sums over arcs and features taken
by other routines), over perfect and lossy links, on a model's samples and on recorded ones, continuing and episodic.
Skipped, with the reason, where JAX is not installed (the extra ``dgtd[jax]``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from helpers import assert_same_run

from dgtd.algorithms import ALGORITHMS, make_algorithm
from dgtd.channels import Arcs
from dgtd.channels.imperfect import Imperfect
from dgtd.channels.lossy import Lossy
from dgtd.errors import DgtdInputError
from dgtd.graphs import topologies
from dgtd.graphs.random import random_edges
from dgtd.problems import tasks
from dgtd.problems.generators import random_mdp_problem, random_problem
from dgtd.run.loop import RunSettings, run
from dgtd.sources.model import Sampling

pytest.importorskip("jax", reason="JAX is not installed (pip install 'dgtd[jax]')")

CASES = {
    "iid-noise": lambda: (random_problem(6, 5, 4, np.random.default_rng(3), reward_noise="bernoulli"), Sampling()),
    "off-policy-markov": lambda: (
        random_mdp_problem(5, (2, 2, 1, 2, 2), 4, np.random.default_rng(5), off_policy=True),
        Sampling("markov"),
    ),
    "shared-tabular": lambda: (random_problem(9, 5, 9, np.random.default_rng(6)), Sampling("markov", True)),
    "episodic": lambda: (tasks.boyan(n_agents=5, n_states=8), Sampling("markov")),
}


def both(problem, sampling, algorithm, channel=None, T=300):
    network = random_edges(topologies.ring_with_chords(problem.n_agents, 2), 0.6)
    settings = RunSettings(iterations=T, seeds=2, seed=11, checkpoints=4, block_size=97)
    return tuple(
        run(problem, network, algorithm, sampling, dataclasses.replace(settings, backend=b), channel=channel)
        for b in ("numpy", "jax")
    )


def assert_same(ref, fast):
    assert_same_run(ref, fast, 1e-12, 1e-14)


@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.parametrize("name", sorted(ALGORITHMS))
def test_jax_gives_the_reference_numbers(name, case):
    problem, sampling = CASES[case]()
    assert_same(*both(problem, sampling, make_algorithm(name, alpha0=0.05, beta=10.0)))


@pytest.mark.parametrize("name", [n for n in sorted(ALGORITHMS) if ALGORITHMS[n].messages])
def test_jax_gives_the_reference_numbers_over_bursty_reweighted_lossy_links(name):
    problem, sampling = CASES["iid-noise"]()
    arcs = Arcs.of(topologies.ring_with_chords(problem.n_agents, 2).edges, problem.n_agents)
    loss = np.linspace(0.05, 0.4, arcs.n_arcs)
    channel = Lossy(loss, burst=3.0, reweight=True)
    ref, fast = both(problem, sampling, make_algorithm(name, alpha0=0.05, beta=10.0), channel)
    assert ref.info["counts"]["messages"].sum() < 2 * arcs.n_arcs * 300 * 2 * len(ALGORITHMS[name].messages)
    assert_same(ref, fast)


def test_jax_refuses_late_messages_in_one_line():
    problem, sampling = CASES["iid-noise"]()
    arcs = 2 * topologies.ring_with_chords(problem.n_agents, 2).n_edges
    with pytest.raises(DgtdInputError, match="--backend jax runs perfect and lossy links") as refused:
        both(problem, sampling, make_algorithm("dgtd"), Imperfect(Lossy(np.zeros(arcs)), delay=2))
    assert "\n" not in str(refused.value)


def test_jax_is_a_backend_of_the_command_line(tmp_path, run_cli):
    out = tmp_path / "r"
    code, _, err = run_cli("run", "paper-example-1", "-T", "2000", "--seeds", "2", "--backend", "jax", "--out", out)
    assert code == 0, err
    assert (out / "metrics.csv").exists() and (out / "summary.json").exists()


def test_jax_on_a_cpu_says_so_in_the_header(tmp_path, run_cli):
    """--backend jax on a CPU was the slowest backend with no notice."""
    from dgtd.backends import jax as on_jax

    code, text, err = run_cli(
        "run", "paper-example-1", "-T", 20, "--backend", "jax", "--no-plots", "--no-progress", "--out", tmp_path / "o"
    )
    assert code == 0, err
    assert ("JAX runs on this machine's CPU" in text) == on_jax.on_cpu()
