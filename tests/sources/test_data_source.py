"""Offline distributed evaluation on recorded transitions: a round trip from a model problem, and bad files."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import record

from dgtd.algorithms import make_algorithm
from dgtd.errors import DgtdInputError
from dgtd.graphs import topologies
from dgtd.graphs.random import random_edges
from dgtd.problems import exact
from dgtd.run.loop import RunSettings, run
from dgtd.sources.data import DataSource, TransitionFile
from dgtd.sources.model import ModelSource, SamplerTables, Sampling


@pytest.fixture(scope="module")
def recorded(
    tmp_path_factory,
):
    import pyarrow as pa
    import pyarrow.parquet as pq

    from dgtd.problems.tasks import garnet

    problem = garnet(n_states=8, branching=3, n_agents=3, n_features=3, seed=1)
    path = tmp_path_factory.mktemp("data") / "transitions.parquet"
    pq.write_table(pa.table(record(problem, seeds=8, steps=20_000)), path)
    return problem, path


def test_recorded_transitions_give_the_models_w_star(recorded):
    """8 recordings x 20,000 steps x 3 agents: the LSTD reference within 4 standard errors of the exact w*."""
    problem, path = recorded
    ref = TransitionFile(path).reference(problem.gamma)
    w = exact.w_star(exact.Moments(problem))
    assert np.all(np.abs(ref.w_star - w) <= 4 * ref.w_star_stderr + 1e-9), (ref.w_star, w, ref.w_star_stderr)


def test_dgtd_on_the_recordings_reaches_the_reference(recorded):
    """Each recording is a seed; DGTD's tail average within 3 % of the reference in value error (2 seeds)."""
    problem, path = recorded
    data = TransitionFile(path)
    ref = data.reference(problem.gamma)
    result = run(
        ref,
        random_edges(topologies.ring(3), 1.0),
        make_algorithm("dgtd"),
        Sampling(),
        RunSettings(iterations=20_000, seeds=2, checkpoints=5),
        source=DataSource(data, seed_ids=[0, 1]),
    )
    assert result.metrics["value_error_tail"][-1].max() < 0.03


@pytest.mark.parametrize(
    "change, words",
    [
        (lambda c: c.pop("reward"), "lacks the column(s) reward"),
        (lambda c: c.update(agent=c["agent"].astype(float) + 0.5), "column agent must hold integers"),
        (lambda c: c.update(phi_0=np.full(len(c["phi_0"]), np.nan)), "column phi_0 must hold finite numbers"),
        (lambda c: c.pop("next_phi_1"), "next_phi_0 .. next_phi_2"),
        (lambda c: c.update(action=c["agent"]), "has column(s) action that dgtd does not read"),
        (lambda c: c.update(state=c["agent"], next_state=c["agent"]), "state, next_state that dgtd does not read"),
    ],
)
def test_a_bad_transitions_file_is_one_line(tmp_path, change, words):
    from dgtd.problems.tasks import garnet

    cols = record(garnet(n_states=5, branching=2, n_agents=2, n_features=3, seed=0), seeds=2, steps=10)
    change(cols)
    np.savez(tmp_path / "t.npz", **cols)
    with pytest.raises(DgtdInputError, match=words.replace("(", r"\(").replace(")", r"\)")):
        TransitionFile(tmp_path / "t.npz")


def test_a_recording_with_a_missing_row_is_refused(tmp_path):
    from dgtd.problems.tasks import garnet

    cols = record(garnet(n_states=5, branching=2, n_agents=2, n_features=3, seed=0), seeds=2, steps=10)
    keep = np.ones(len(cols["seed"]), bool)
    keep[3] = False
    with pytest.raises(DgtdInputError, match="every agent at every step"):
        TransitionFile(save({k: v[keep] for k, v in cols.items()}, tmp_path / "t.npz"))


def save(cols: dict, path):
    np.savez(path, **cols)
    return path


def test_a_repeated_row_in_place_of_a_missing_one_is_refused(tmp_path):
    from dgtd.problems.tasks import garnet

    cols = record(garnet(n_states=5, branching=2, n_agents=2, n_features=3, seed=0), seeds=2, steps=10)
    cols["step"][3] = cols["step"][5]  # the counts still match; one cell twice, another never
    cols["agent"][3] = cols["agent"][5]
    with pytest.raises(DgtdInputError, match="a row is repeated and another missing"):
        TransitionFile(save(cols, tmp_path / "t.npz"))


def test_a_file_read_in_small_batches_gives_the_same_rows_in_every_format(tmp_path, monkeypatch):
    """Parquet and CSV are streamed in batches of BATCH_ROWS rows; with 100-row batches (and the rows shuffled,
    so that a batch mixes recordings and steps) the disk-backed rows and the reference equal those of one .npz."""
    import pyarrow as pa
    import pyarrow.csv as pcsv
    import pyarrow.parquet as pq

    import dgtd.sources.data as data
    from dgtd.problems.tasks import garnet

    cols = record(garnet(n_states=5, branching=2, n_agents=3, n_features=3, seed=0), seeds=3, steps=200)
    order = np.random.default_rng(0).permutation(len(cols["seed"]))
    cols = {k: v[order] for k, v in cols.items()}
    whole = TransitionFile(save(cols, tmp_path / "t.npz"))
    monkeypatch.setattr(data, "BATCH_ROWS", 100)
    pq.write_table(pa.table(cols), tmp_path / "t.parquet", row_group_size=100)
    pcsv.write_csv(pa.table(cols), tmp_path / "t.csv")
    for name in ("t.parquet", "t.csv"):
        part = TransitionFile(tmp_path / name)
        np.testing.assert_array_equal(np.asarray(part.rows), np.asarray(whole.rows))
        np.testing.assert_allclose(part.reference(0.9).w_star, whole.reference(0.9).w_star, rtol=1e-12)


def test_state_index_columns_give_tabular_features_and_the_models_w_star(tmp_path):
    """state and next_state instead of feature columns: one-hot features, and with a tabular model (Phi = I) the
    reference is the model's w* within 4 standard errors (8 recordings x 5,000 steps x 3 agents)."""
    from dgtd.problems.model import make_problem
    from dgtd.problems.tasks import garnet

    g = garnet(n_states=5, branching=2, n_agents=3, n_features=3, seed=2)
    problem = make_problem(g.P, g.R, np.eye(5), g.gamma)
    tables = SamplerTables.build(problem, exact.Moments(problem).d)
    src = ModelSource(problem, random_edges(topologies.ring(3), 1.0), Sampling(), tables, 4, range(8))
    src.start()
    blk = src.next_block(5000)
    T, B, N = blk.r.shape
    t, b, i = np.meshgrid(np.arange(T), np.arange(B), np.arange(N), indexing="ij")
    np.savez(
        tmp_path / "tab.npz",
        seed=b.ravel(),
        step=t.ravel(),
        agent=i.ravel(),
        reward=blk.r.ravel(),
        state=blk.s.ravel(),
        next_state=blk.s_next.ravel(),
    )
    data = TransitionFile(tmp_path / "tab.npz")
    assert data.tabular and data.q == 5
    ref = data.reference(problem.gamma)
    w = exact.w_star(exact.Moments(problem))
    assert np.all(np.abs(ref.w_star - w) <= 4 * ref.w_star_stderr), (ref.w_star, w, ref.w_star_stderr)


@pytest.fixture(scope="module")
def episodes(tmp_path_factory):
    """One dataset of 400 episodes of 100 steps (no seed column): one long recording of a Garnet chain cut up."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from dgtd.problems.tasks import garnet

    problem = garnet(n_states=8, branching=3, n_agents=3, n_features=3, seed=1)
    cols = record(problem, seeds=1, steps=40_000)
    cols["episode"], cols["step"] = cols["step"] // 100, cols["step"] % 100
    del cols["seed"]
    path = tmp_path_factory.mktemp("episodes") / "episodes.parquet"
    pq.write_table(pa.table(cols), path)
    return problem, path


def test_a_dataset_of_episodes_gives_the_models_w_star_and_dgtd_reaches_it(episodes):
    """Episodes without recordings: the reference's 8 groups are the episodes dealt in turn (within 4 standard
    errors of the exact w*), and two seeds, each replaying every episode in its own order, end within 3 % of it."""
    problem, path = episodes
    data = TransitionFile(path)
    assert data.recordings is None and len(data.units) == 400 and len(data.groups) == 8
    ref = data.reference(problem.gamma)
    w = exact.w_star(exact.Moments(problem))
    assert np.all(np.abs(ref.w_star - w) <= 4 * ref.w_star_stderr), (ref.w_star, w, ref.w_star_stderr)
    result = run(
        ref,
        random_edges(topologies.ring(3), 1.0),
        make_algorithm("dgtd"),
        Sampling(),
        RunSettings(iterations=40_000, seeds=2, checkpoints=5),
        source=DataSource(data, [0, 1], seed=3),
    )
    assert result.metrics["value_error_tail"][-1].max() < 0.03


def test_a_seeds_order_of_episodes_does_not_depend_on_the_other_seeds(episodes):
    _, path = episodes
    data = TransitionFile(path)
    one, two = DataSource(data, [1], seed=5), DataSource(data, [0, 1], seed=5)
    a, b = one.next_block(300), two.next_block(300)
    assert np.array_equal(a.r[:, 0], b.r[:, 1]) and not np.array_equal(b.r[:, 0], b.r[:, 1])
    stream = np.concatenate([data.rows[data.offsets[u] : data.offsets[u + 1], :, 2 * data.q] for u in data.order(5, 1)])
    assert np.array_equal(a.r[:, 0], stream[:300])  # episode after episode, in the seed's order


def test_a_run_on_recordings_draws_the_links_of_its_network(recorded):
    """The recordings hold the agents' transitions, not their links: those come from the run's network. With each
    link of the ring up with probability 0.5, about half the messages of a fixed ring are sent (20,000 steps x 3
    links x 2 seeds: the fraction's standard error is 0.5 / sqrt(120,000) = 0.0014, so 0.01 is 7 of them), and DGTD
    still reaches the reference."""
    problem, path = recorded
    data = TransitionFile(path)
    ref = data.reference(problem.gamma)
    settings = RunSettings(iterations=20_000, seeds=2, checkpoints=5)
    networks = {p: random_edges(topologies.ring(3), p) for p in (1.0, 0.5)}
    runs = {
        p: run(
            ref,
            net,
            make_algorithm("dgtd"),
            Sampling(),
            settings,
            source=DataSource(data, seed_ids=[0, 1], network=net),
        )
        for p, net in networks.items()
    }
    sent = {p: r.info["messages"].sum() for p, r in runs.items()}
    assert abs(sent[0.5] / sent[1.0] - 0.5) < 0.01, sent
    assert runs[0.5].metrics["value_error_tail"][-1].max() < 0.03


def test_a_folder_given_as_the_transitions_file_is_named_so(tmp_path):
    with pytest.raises(DgtdInputError, match="is a directory, not a file"):
        TransitionFile(tmp_path)
