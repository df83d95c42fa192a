"""The SIS epidemic as a networked MDP (`dgtd.problems.epidemic`): its tables by hand, its heuristics, and the
learners' comparison on it."""

from __future__ import annotations

import numpy as np
import pytest

from dgtd.errors import DgtdInputError
from dgtd.graphs import topologies
from dgtd.problems.epidemic import epidemic, heuristics
from dgtd.run.networked import torus


def test_the_tables_by_hand():
    """Agent 1 of a path of 3 (neighbours 0 and 2; its row's digits: itself, then 0, then 2)."""
    mdp = epidemic(topologies.path(3).edges, 3, spread=0.3, recover=0.1, treated=0.6, protection=0.5, cost=0.3)
    P = mdp.P[1]
    # susceptible, both neighbours infected (row 0b011): caught with 1 - 0.7^2 = 0.51, treated 0.255
    assert P[0b011, 0, 1] == pytest.approx(0.51) and P[0b011, 1, 1] == pytest.approx(0.255)
    assert P[0b000, 0, 1] == 0.0  # no infected neighbour: never caught
    # infected: recovers with 0.1 waiting, 0.6 treated, whatever its neighbours
    assert P[0b100, 0, 0] == pytest.approx(0.1) and P[0b111, 1, 0] == pytest.approx(0.6)
    assert mdp.R[1].tolist() == [[0.0, -0.3], [-1.0, -1.3]]
    with pytest.raises(DgtdInputError, match="probabilities are in"):
        epidemic(topologies.path(3).edges, 3, spread=1.5)


def test_treating_while_infected_beats_never_treating_exactly():
    """On a ring of 5 (the joint table: exact J_gamma), treating while infected is worth more than never treating
    (recovery 0.6 against 0.1 at a cost of 0.3) and than always treating."""
    from dgtd.run.scalable import exact_return

    mdp = epidemic(topologies.ring(5).edges, 5)
    J = {name: exact_return(mdp, p) for name, p in heuristics(mdp).items()}
    assert J["treat while infected"] > J["never treat"] and J["treat while infected"] > J["always treat"], J


def test_a_torus_grid():
    edges = torus(3, 4)
    degrees = np.bincount(edges.ravel(), minlength=12)
    assert len(edges) == 24 and (degrees == 4).all()


def test_the_epidemic_is_compared(run_cli, tmp_path, few_rollouts):
    code, text, err = run_cli("compare", "epidemic", "--agents", 30, "-T", 60, "--seeds", 1, "--no-progress",
                              "--no-plots", "--out", tmp_path / "c")  # fmt: skip
    assert code == 0 and "heuristic (best of 3)" in text, err
