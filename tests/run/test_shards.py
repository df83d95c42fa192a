"""A run's numbers do not depend on how its agents are laid out: sums over the agents up their fixed tree are one
process's bit for bit, and a checkpoint written as shards (one a rank) resumes in one process, or on any number
of ranks, with the numbers of an uninterrupted run. (The MPI runs themselves: tests/run/test_mpi.py.)"""

from __future__ import annotations

import functools

import numpy as np
import pytest
from test_checkpoint import assert_same_run

from dgtd.config import make_channel, resolve, unflat
from dgtd.errors import DgtdInputError
from dgtd.problems import exact
from dgtd.run.checkpoint import assemble, load_checkpoint, save_checkpoint
from dgtd.run.loop import run as run_loop
from dgtd.run.state import AGENT_AXES


@pytest.mark.parametrize("n", [1, 2, 7, 1000, 1024, 1025])
def test_a_sum_over_the_fixed_tree_of_agents_is_the_same_however_the_rows_are_split(n):
    """The consensus metric's sums over a fixed tree of the agents (`dgtd.problems.exact.tree_sum`): each rank sums
    the aligned power-of-two blocks within its rows, the blocks of every rank are combined up the same tree: bit for
    bit the sum of one process, for any split (contiguous, as ranks hold them), and the plain sum to 1e-12."""
    rng = np.random.default_rng(n)
    x = rng.standard_normal((3, n, 4)) * 10.0 ** rng.integers(-8, 8, (1, n, 1))

    def tree(lo: int, size: int) -> np.ndarray:  # the fixed tree by its definition: halves of [lo, lo + size)
        return (
            x[:, lo]
            if size == 1
            else tree(lo, size // 2) + (tree(lo + size // 2, size // 2) if lo + size // 2 < n else 0.0)
        )

    whole = exact.tree_sum(x)
    assert np.array_equal(whole, tree(0, 1 << max(1, n - 1).bit_length()))
    np.testing.assert_allclose(whole, x.sum(axis=1), rtol=1e-12, atol=1e-300 + 1e-12 * np.abs(x).sum(axis=1).max())
    for ranks in (2, 3, 8, 64):
        bounds = np.linspace(0, n, ranks + 1).astype(int)
        pieces = exact.joined([exact.tree_pieces(x[:, lo:hi], lo) for lo, hi in zip(bounds[:-1], bounds[1:])])
        assert np.array_equal(exact.tree_total(pieces, n, x.shape[:1] + x.shape[2:]), whole)
    W = rng.standard_normal((2, n, 3))
    np.testing.assert_allclose(exact.ordered_consensus_error(W, n), exact.consensus_error(W), rtol=1e-12, atol=1e-12)


class _Ranks:
    """mpi4py's communicator as `save_checkpoint` uses it, for rank ``rank`` of ``size`` (one process plays each
    rank in turn: the barrier has nothing to wait for)."""

    def __init__(self, rank: int, size: int):
        self.rank, self.size = rank, size

    def Get_rank(self):
        return self.rank

    def Get_size(self):
        return self.size

    def Barrier(self):
        pass


def _shard(snap: dict, agents: np.ndarray, dst: np.ndarray) -> dict:
    """A rank's snapshot of a one-process one: the rows of ``agents``, the arcs into them, their chains' states."""
    arcs = np.flatnonzero(np.isin(dst, agents))

    def rows(x, axis):
        return np.take(x, agents, axis=axis)

    out = {key: v for key, v in snap.items()}
    for name, axis in AGENT_AXES.items():
        value = snap.get(name)
        if isinstance(value, dict):
            out[name] = {f: rows(x, axis) for f, x in value.items()}
        elif value is not None:
            out[name] = rows(value, axis)
    channel = dict(snap["channel"])
    for name, x in channel.items():
        if np.ndim(x) >= 2 and x.shape[0] and x.shape[1] == len(dst):
            channel[name] = x[:, arcs]
    out["channel"] = channel
    if np.ndim(snap["per_arc"]) == 2 and snap["per_arc"].shape[1]:
        out["per_arc"] = snap["per_arc"][:, arcs]
    out["source"] = {**snap["source"], "current": snap["source"]["current"][:, agents], "agents": agents}
    return {**out, "agents": agents, "arcs": arcs}


@pytest.fixture(scope="module")
def lossy_markov_run():
    spec = unflat(
        dict(
            scenario="paper-example-1",
            iterations=1800,
            seeds=2,
            backend="numpy",
            sampling="markov",
            edge_prob=0.7,
            loss=0.3,
            burst=4.0,
            delay=2,
            wake=0.8,
            checkpoints=12,
            block_size=250,
        )
    )
    problem, network, algorithm, samp, settings, resolved, channel = resolve(spec)
    run = functools.partial(
        run_loop, problem, network, algorithm, samp, settings, channel=make_channel(resolved, network)
    )
    snaps = []
    whole = run(checkpoint_every=600, on_checkpoint=snaps.append)
    return run, whole, snaps, network


def test_a_checkpoint_in_shards_resumes_in_one_process_with_the_same_numbers(tmp_path, lossy_markov_run):
    """Agents 3, 0 on one rank and 4, 1, 2 on another (not in order), each with the arcs into its agents (copies,
    messages in flight, bursty links, per-arc counts) and its agents' Markov chains: written as a set of shards,
    read back and assembled by id, the run continues to the uninterrupted numbers."""
    run, whole, snaps, network = lossy_markov_run
    from dgtd.channels import Arcs

    dst = Arcs.of(network.base.edges, network.n_nodes).dst
    parts = [np.array([3, 0]), np.array([4, 1, 2])]
    path = tmp_path / "checkpoint.npz"
    for rank in (1, 0):  # rank 0 commits the set last
        save_checkpoint(path, _shard(snaps[1], parts[rank], dst), {"spec": "x"}, _Ranks(rank, 2))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["checkpoint.1200.1.npz", "checkpoint.npz"]
    snap, config = load_checkpoint(path)
    assert config == {"spec": "x"} and [p.name for p in snap["shards"]] == ["checkpoint.1200.1.npz"]
    assert_same_run(whole, run(resume=snap))
    # a rank holding agents 1 and 2 takes their rows, and those of the arcs into them, from either shard
    mine = assemble(snap, 5, len(dst), np.array([2, 1]), np.flatnonzero(np.isin(dst, [1, 2])), np.array([2, 1]))
    np.testing.assert_array_equal(mine["state"]["w"], snaps[1]["state"]["w"][:, [2, 1]])
    np.testing.assert_array_equal(mine["source"]["current"], snaps[1]["source"]["current"][:, [2, 1]])
    np.testing.assert_array_equal(mine["channel"]["copies"], snaps[1]["channel"]["copies"][:, np.isin(dst, [1, 2])])


def test_a_set_of_shards_is_committed_whole_or_not_at_all(tmp_path, lossy_markov_run):
    """The shards of a new checkpoint written but rank 0's not (a run killed in between): the previous set is what
    is read, its shards kept; once committed, the previous shards go. A shard missing is one line."""
    _, _, snaps, network = lossy_markov_run
    from dgtd.channels import Arcs

    dst = Arcs.of(network.base.edges, network.n_nodes).dst
    parts = [np.array([0, 1]), np.array([2, 3, 4])]
    path = tmp_path / "checkpoint.npz"
    for rank in (1, 0):
        save_checkpoint(path, _shard(snaps[0], parts[rank], dst), {}, _Ranks(rank, 2))
    save_checkpoint(path, _shard(snaps[1], parts[1], dst), {}, _Ranks(1, 2))  # killed before rank 0 commits
    snap, _ = load_checkpoint(path)
    assert snap["k"] == 600 and [p.name for p in snap["shards"]] == ["checkpoint.600.1.npz"]
    save_checkpoint(path, _shard(snaps[1], parts[0], dst), {}, _Ranks(0, 2))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["checkpoint.1200.1.npz", "checkpoint.npz"]
    (tmp_path / "checkpoint.1200.1.npz").unlink()
    with pytest.raises(DgtdInputError, match="names shards that are not there"):
        load_checkpoint(path)


@pytest.mark.parametrize("algorithm", ["td0", "dgtd"])
def test_the_consensus_error_of_many_agents_numbered_at_random_is_summed_in_storage_order(algorithm):
    """300 agents on a ring numbered at random (reordered for storage, `storage_order`): the consensus metric is the
    plain one to 1e-12 for a distributed method, and 0 for a centralised learner (one estimate, no agents' rows to
    reorder)."""
    from dgtd.algorithms import make_algorithm
    from dgtd.graphs.random import random_edges
    from dgtd.graphs.topologies import from_edges
    from dgtd.problems import tasks
    from dgtd.run.loop import RunSettings, Sampling

    n = 300
    label = np.random.default_rng(1).permutation(n)
    ring = from_edges(n, np.stack([label, np.roll(label, 1)], 1))
    problem = tasks.garnet(10, 2, n, 3, seed=0)
    settings = RunSettings(iterations=200, seeds=2, checkpoints=4, backend="numpy")
    result = run_loop(problem, random_edges(ring, 0.8), make_algorithm(algorithm), Sampling(), settings)
    consensus = result.metrics["consensus"][-1]
    np.testing.assert_allclose(consensus, exact.consensus_error(result.w_last), rtol=1e-12, atol=0)
    assert np.all(consensus == 0) == (algorithm == "td0")
