"""An algorithm's contract checked in one line before anything compiles, and the compiled step shown as text."""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import pytest

import dgtd
from dgtd.algorithms import ALGORITHMS
from dgtd.algorithms.base import check_contract
from dgtd.backends.compiled import source_of
from dgtd.errors import DgtdInputError


class NoW(NamedTuple):
    v: np.ndarray


@dataclass(frozen=True)
class WithoutW(dgtd.TD0):
    def init(self, seeds, agents, features):
        return NoW(np.zeros((seeds, agents, features)))


class Flat(NamedTuple):
    w: np.ndarray


@dataclass(frozen=True)
class FlatState(dgtd.TD0):
    def init(self, seeds, agents, features):
        return Flat(np.zeros((seeds, agents * features)))


@pytest.mark.parametrize("cls", list(ALGORITHMS.values()))
def test_every_registered_algorithm_keeps_the_contract(cls):
    check_contract(cls())


@pytest.mark.parametrize(
    "algorithm, said", [(WithoutW(), "has no field w"), (FlatState(), "field w is not (B, N or 1, q)")]
)
def test_a_broken_contract_is_one_line_before_the_run_compiles(algorithm, said, monkeypatch):
    with pytest.raises(DgtdInputError, match=re.escape(said)) as e:
        check_contract(algorithm)
    assert "\n" not in str(e.value)
    import dgtd.run.layout as layout

    monkeypatch.setattr(layout, "kernel_for", lambda *a: pytest.fail("a kernel was made for a broken algorithm"))
    sc = dgtd.scenario("paper-example-1")
    with pytest.raises(DgtdInputError, match=re.escape(said)):
        dgtd.evaluate(sc.problem, sc.network, algorithm, iterations=10, backend="numba")


def test_the_compiled_step_shows_its_algorithms_lines_template_and_accessors():
    text = source_of(dgtd.TDCTracking())
    assert "feature: " in text and "tdc_tracking.py:" in text  # its own functions, by file and line
    assert "def _agent(" in text and "def features(" in text  # the template
    for accessor in ("PRODUCTS", "LOAD_STATE", "LOAD_HEARD", "STORE", "LOAD_TERMS", "ADD_TERMS"):
        assert f"def {accessor}(" in text
    assert "own[0, b, i, f]" in text  # spelled out for its fields
    assert "def _centralised(" in source_of(dgtd.make_algorithm("tdc"))
