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


def test_a_generated_tasks_memory_is_measured_on_two_small_builds():
    """garnet's arrays grow linearly in the agents (its rewards' rows, its network's links): the estimate from 200 and
    400 agents is within 1 % of the arrays of the task built at 5 000."""
    from dgtd.scenarios import get_scenario

    def make(n):
        return get_scenario("garnet", n_agents=n)

    built = memory.array_bytes(make(5000))
    assert abs(memory.probed_bytes(make, 5000) - built) < 0.01 * built


@pytest.mark.parametrize(
    "args, words",
    [
        (("run", "garnet", "--agents", 100_000_000, "--graph", "small-world"), ("garnet with 100,000,000 agents",)),
        (("learn", "factored", "--agents", 10_000_000), ("factored with 10,000,000 agents", "--actor centralised")),
        (("learn", "factored", "--agents", 30_000), ("networked learners",)),  # their estimates: N^2 S A numbers
    ],
)
def test_a_task_too_large_is_refused_before_it_is_built(run_cli, monkeypatch, tmp_path, args, words):
    """With 8 GB free, garnet of 10^8 agents (it grew to 23.6 GB and was killed by the kernel) and factored learners
    of 10^7 agents (numpy's "Unable to allocate 14.2 PiB" after 21 s), and networked ones of 30 000 (288 GB of
    team-reward estimates), are refused in one line naming the memory needed and free, before anything is built."""
    from helpers import one_line_error

    monkeypatch.setattr(memory, "available_bytes", lambda: 8 * 10**9)
    code, out, err = run_cli(*args, "-T", 10, "--no-progress", "--out", tmp_path / "o")
    one_line_error(code, out, err, "GB, more than the 8.0 GB free", *words)
