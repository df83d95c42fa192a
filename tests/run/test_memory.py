"""The memory check before a run (`dgtd.run.memory.check_memory`): one line where the run does not fit, counting what
a rank holds where the agents are spread (its share of the agents and arcs) times the ranks on its machine."""

from __future__ import annotations

import pytest

from dgtd.algorithms import make_algorithm
from dgtd.errors import DgtdInputError
from dgtd.run import memory

DGTD = make_algorithm("dgtd")
RUN = dict(seeds=4, agents=1_000_000, features=8, arcs=6_000_000, checkpoints=10, backend="numba")


def test_a_ranks_share_is_its_agents_and_arcs_rounded_up(monkeypatch):
    """Spread over 8 ranks, one a machine: a rank needs run_bytes of N / 8 agents and arcs; a machine with a little
    more than that free runs it, one with a little less refuses it in one line that names the share."""
    share = memory.run_bytes(DGTD, 4, 125_000, 8, 750_000, 10, "numba")
    assert share < memory.run_bytes(DGTD, **RUN) / 7
    monkeypatch.setattr(memory, "available_bytes", lambda: share + 1)
    memory.check_memory(DGTD, **RUN, ranks=8, here=1)
    with pytest.raises(DgtdInputError, match="needs about"):
        memory.check_memory(DGTD, **RUN)  # the whole run in one process does not fit
    monkeypatch.setattr(memory, "available_bytes", lambda: share - 1)
    with pytest.raises(DgtdInputError, match="this rank needs about .* 125,000 agents a rank of 8"):
        memory.check_memory(DGTD, **RUN, ranks=8, here=1)


def test_the_ranks_on_one_machine_share_its_memory(monkeypatch):
    """8 ranks, 4 on this machine: they need 4 shares together, and the most seeds that fit are counted for the 4."""
    share = memory.run_bytes(DGTD, 4, 125_000, 8, 750_000, 10, "numba")
    monkeypatch.setattr(memory, "available_bytes", lambda: 4 * share - 1)
    memory.check_memory(DGTD, **RUN, ranks=8, here=3)
    with pytest.raises(DgtdInputError, match="the 4 ranks on this machine") as refused:
        memory.check_memory(DGTD, **RUN, ranks=8, here=4)
    one = memory.run_bytes(DGTD, 1, 125_000, 8, 750_000, 10, "numba")
    assert f"at most {(4 * share - 1) // (4 * one):,}" in str(refused.value)
