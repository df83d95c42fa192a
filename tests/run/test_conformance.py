"""`dgtd.check_algorithm` on a user's own algorithm: one written in the one definition runs compiled and on JAX from its
class alone and passes; one that breaks what the backends rely on is told what."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import pytest
from envs.algorithms import RelaxedConsensusTD0  # a user's algorithm, not registered

import dgtd
from dgtd.algorithms.base import zeros


def test_a_users_algorithm_in_the_one_definition_passes_on_every_backend():
    report = dgtd.check_algorithm(RelaxedConsensusTD0(alpha0=0.05, beta=10.0))
    assert set(report) == {"iid-noise", "markov-off-policy", "tabular-shared", "episodic", "recorded"}
    for case, differences in report.items():
        assert "numba" in differences
        assert all(d <= 1e-9 for d in differences.values()), (case, differences)


def test_an_algorithm_that_writes_update_alone_is_told_it_cannot_run_compiled():
    @dataclass(frozen=True)
    class OwnUpdate(RelaxedConsensusTD0):
        def update(self, state, sample, inbox, alpha):
            return super().update(state, sample, inbox, 0.5 * alpha)

    with pytest.raises(AssertionError, match="writes update alone"):
        dgtd.check_algorithm(OwnUpdate())


def test_a_state_that_lists_what_it_sends_first_is_told_so():
    class Sent(NamedTuple):
        w: np.ndarray
        theta: np.ndarray

    @dataclass(frozen=True)
    class SendsFirst(RelaxedConsensusTD0):
        def init(self, seeds, agents, features):
            return Sent(*zeros(seeds, agents, features, 2))

    with pytest.raises(AssertionError, match="lists what it sends before what it keeps"):
        dgtd.check_algorithm(SendsFirst())


def test_a_users_algorithm_whose_fields_have_no_defaults_gets_a_compiled_step():
    """The compiled step is made from the algorithm the user runs, not from a default instance of its class (which a
    class with a required field does not have)."""
    from dgtd.backends.compiled import step_of

    @dataclass(frozen=True, kw_only=True)
    class Required(RelaxedConsensusTD0):
        tag: str  # no default

    step = step_of(Required(tag="mine"))
    assert step is not None and step.own == () and not step.degrees
