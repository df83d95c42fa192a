"""Helpers that tests in several folders share (tests/ is on pytest's python path: pyproject.toml)."""

from __future__ import annotations

import numpy as np

from dgtd.graphs import topologies
from dgtd.graphs.random import random_edges
from dgtd.problems import exact
from dgtd.sources.model import ModelSource, SamplerTables, Sampling


def one_line_error(code, out, err, *words):
    """A refusal as the CLI gives it: exit code 2, one line `dgtd: error: ...` holding ``words``, no traceback."""
    assert code == 2, (out, err)
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("dgtd: error:"), err
    assert "Traceback" not in out + err
    for w in words:
        assert w in lines[0], lines[0]


def record(problem, seeds: int, steps: int) -> dict:
    """Columns of every agent's own transitions from the model (independent copies, i.i.d. s ~ d)."""
    tables = SamplerTables.build(problem, exact.Moments(problem).d)
    src = ModelSource(
        problem, random_edges(topologies.ring(problem.n_agents), 1.0), Sampling(), tables, 9, range(seeds)
    )
    src.start()
    blk = src.next_block(steps)
    T, B, N = blk.r.shape
    t, b, i = np.meshgrid(np.arange(T), np.arange(B), np.arange(N), indexing="ij")
    cols = {"seed": b.ravel(), "step": t.ravel(), "agent": i.ravel(), "reward": blk.r.ravel()}
    phi, nphi = problem.Phi[blk.s.ravel()], problem.Phi[blk.s_next.ravel()]
    for j in range(problem.n_features):
        cols[f"phi_{j}"], cols[f"next_phi_{j}"] = phi[:, j], nphi[:, j]
    return cols


def assert_same_run(ref, fast, rtol: float, metrics_atol: float) -> None:
    """Two runs' final states, averaged iterates and metrics equal to ``rtol`` (absolute: rtol x the iterates' scale;
    metrics: ``metrics_atol``), their message counts exactly: a backend against the reference."""
    from numpy.testing import assert_allclose, assert_array_equal

    assert np.abs(ref.w_last).max() > 0
    scale = max(1.0, float(np.abs(ref.w_last).max()))
    for key in ref.final_state:
        assert_allclose(fast.final_state[key], ref.final_state[key], rtol=rtol, atol=rtol * scale)
    assert_allclose(fast.w_avg, ref.w_avg, rtol=rtol, atol=rtol * scale)
    for key in ref.metrics:
        assert_allclose(fast.metrics[key], ref.metrics[key], rtol=rtol, atol=metrics_atol)
    for key in ref.info["counts"]:
        assert_array_equal(fast.info["counts"][key], ref.info["counts"][key])


# The compiled agent layout compiles kernels of its own per algorithm (10-15 s each on a fresh machine): the default
# suite runs it for DGTD and TDC tracking (the most state, two messages), `pytest -m slow` for every other method.
DEFAULT_AGENT_LAYOUT = ("dgtd", "tdc-tracking")


def agent_layout_param(*values):
    """A test parameter (a method's name first) running the agent layout: slow beyond `DEFAULT_AGENT_LAYOUT`."""
    import pytest

    return pytest.param(*values, marks=() if values[0] in DEFAULT_AGENT_LAYOUT else (pytest.mark.slow,))
