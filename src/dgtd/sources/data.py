"""Samples from recorded transitions: offline distributed evaluation on a table of what the agents saw.

A table (Parquet, CSV or .npz of columns) holds one row per agent and step:

- ``seed`` and/or ``episode``: which independent recording (a run's seed) and which episode the row belongs to;
- ``step``: its time index within that episode (within the recording, without ``episode``); ``agent``: 0 .. N-1;
- the state: feature columns ``phi_0 .. phi_{q-1}`` and ``next_phi_0 ..`` of the next state, or integer columns
  ``state`` and ``next_state`` (0 .. S-1), whose features are then tabular (one-hot, q = S);
- ``reward``: the agent's own reward; optional ``ratio`` (importance ratio, 1 if absent) and ``terminal`` (1 where
  the transition ended an episode: its TD target is the reward alone).

A column of any other name is refused (nothing the file holds is dropped unread).

Every episode must hold every agent at every step from 0 on. With a ``seed`` column, recording k (in the order of
their ids) is seed k of a run, its episodes one after another, and the reference is LSTD with one group per
recording. With episodes only, there is one dataset and no independent recordings: seed k replays every episode in
an order of its own (drawn from the run's seed and k, so that it does not depend on the other seeds), and the
reference's groups are the episodes dealt in turn into 8 (`dgtd.problems.reference`). `TransitionFile` reads the
file in batches (Parquet and CSV stream; an .npz is read whole) into a disk-backed array, episode after episode,
so that a file larger than memory works and a block of a run reads only its own rows.
"""

from __future__ import annotations

import shutil
import tempfile
import weakref
from pathlib import Path

import numpy as np

from dgtd.errors import DgtdInputError
from dgtd.files import open_npz, present
from dgtd.samples import Block, SampleTable
from dgtd.streams import ORDER, edge_uniforms, seed_key, seed_keys, uniforms

KEYS = ("seed", "episode", "step", "agent")
GROUPS = 8  # the reference's groups of episodes, without independent recordings
STATES = ("state", "next_state")  # tabular states, instead of feature columns
FIX = (
    "give one row per agent and step with columns seed, step, agent, phi_0.., next_phi_0.. (or state, "
    "next_state), reward"
)
BATCH_ROWS = 1 << 16


def _batches(path: Path, columns=None):
    """The file's rows as dicts of NumPy columns, ``BATCH_ROWS`` at a time (an .npz at once)."""
    if path.suffix == ".parquet":
        import pyarrow.parquet as pq

        for batch in pq.ParquetFile(path).iter_batches(batch_size=BATCH_ROWS, columns=columns):
            yield {name: batch.column(name).to_numpy(zero_copy_only=False) for name in batch.schema.names}
    elif path.suffix == ".csv":
        import pyarrow.csv as pcsv

        convert = pcsv.ConvertOptions(include_columns=columns) if columns else None
        size = pcsv.ReadOptions(block_size=BATCH_ROWS * 64)  # bytes: about BATCH_ROWS rows of a few columns
        with pcsv.open_csv(path, read_options=size, convert_options=convert) as reader:
            for batch in reader:
                yield {name: batch.column(name).to_numpy(zero_copy_only=False) for name in batch.schema.names}
    elif path.suffix == ".npz":
        with open_npz(path) as z:
            yield {k: z[k] for k in z.files if columns is None or k in columns}
    else:
        raise DgtdInputError(f"transitions file {path}: give a .parquet, .csv or .npz file")


def _read(path: Path, columns=None):
    try:
        yield from _batches(path, columns)
    except DgtdInputError:
        raise
    except ImportError:
        raise DgtdInputError(
            f"reading {path.suffix} files needs pyarrow: pip install 'dgtd[parquet]' (or give an "
            ".npz of the same columns)"
        ) from None
    except Exception as e:  # noqa: BLE001  (a reader's own error: a damaged or foreign file)
        raise DgtdInputError(f"transitions file {path} cannot be read ({type(e).__name__}: {e}); {FIX}") from None


def _header(path: Path) -> list[str]:
    """The column names, checked: seed or episode, step, agent, reward and phi_j / next_phi_j (or state and
    next_state)."""
    for batch in _read(path):
        names = list(batch)
        break
    else:  # a header alone, or an empty table: it may have every column
        raise DgtdInputError(f"transitions file {path} holds no rows; {FIX}")
    states = STATES if "state" in names and "phi_0" not in names else ("phi_0", "next_phi_0")
    missing = [c for c in ("step", "agent", "reward", *states) if c not in names]
    if "seed" not in names and "episode" not in names:
        missing.insert(0, "seed or episode")
    if missing:
        raise DgtdInputError(f"transitions file {path} lacks the column(s) {', '.join(missing)}; {FIX}")
    q = sum(1 for c in names if c.startswith("phi_"))
    if sorted((c for c in names if c.startswith("phi_")), key=lambda c: int(c[4:]) if c[4:].isdigit() else -1) != [
        f"phi_{j}" for j in range(q)
    ] or any(f"next_phi_{j}" not in names for j in range(q)):
        raise DgtdInputError(
            f"transitions file {path}: the feature columns must be phi_0 .. phi_{q - 1} and "
            f"next_phi_0 .. next_phi_{q - 1}"
        )
    read = {*KEYS, "reward", "ratio", "terminal", *(STATES if states == STATES else ())}
    unread = [c for c in names if c not in read and not (states != STATES and c.startswith(("phi_", "next_phi_")))]
    if unread:  # read to the last column: nothing the file holds is silently dropped
        raise DgtdInputError(
            f"transitions file {path} has column(s) {', '.join(unread)} that dgtd does not read; remove them (it "
            "reads seed, episode, step, agent, reward, ratio, terminal and either state, next_state or phi_j, "
            "next_phi_j)"
        )
    return names


def _checked(path: Path, batch: dict, names) -> dict:
    """A batch's columns as int64 keys and float64 values (a missing seed or episode column: zeros), or a one-line
    error naming the column."""
    lengths = {name: len(batch[name]) for name in names if name in batch}
    if len(set(lengths.values())) > 1:
        listed = ", ".join(f"{name} {n:,}" for name, n in lengths.items())
        raise DgtdInputError(
            f"transitions file {path} has columns of different lengths ({listed}); every column needs one entry per row"
        )
    out = {}
    for name in ("seed", "episode"):
        if name in names and name not in batch:
            out[name] = np.zeros(len(batch["step"]), np.int64)
    for name in (n for n in names if n not in out):
        x = np.asarray(batch[name])
        if name in KEYS or name in STATES:
            try:
                out[name] = x.astype(np.int64, casting="safe")
            except TypeError:
                raise DgtdInputError(
                    f"transitions file {path}: column {name} must hold integers, got {x.dtype}"
                ) from None
        else:
            if x.dtype.kind not in "biuf" or not np.isfinite(x.astype(np.float64)).all():
                raise DgtdInputError(f"transitions file {path}: column {name} must hold finite numbers")
            out[name] = x.astype(np.float64)
    if "ratio" in out and (out["ratio"] < 0).any():
        raise DgtdInputError(
            f"transitions file {path}: column ratio must be >= 0 (an importance ratio pi(a|s) / "
            f"b(a|s)), got {out['ratio'].min():g}"
        )
    if "terminal" in out and not np.isin(out["terminal"], (0.0, 1.0)).all():
        bad = out["terminal"][~np.isin(out["terminal"], (0.0, 1.0))][0]
        raise DgtdInputError(
            f"transitions file {path}: column terminal must be 0 or 1 (1 where the transition ended "
            f"an episode), got {bad:g}"
        )
    return out


class TransitionFile:
    """A transitions table read in two passes: its episodes' keys, lengths and agents, then every row into a
    disk-backed array ``rows`` (total steps, N, 2q + 3) of phi, next phi, reward, ratio and continuing, episode
    after episode (``offsets``), in a temporary directory removed with this object."""

    def __init__(self, path):
        self.path = path = Path(path)
        present(path, "transitions file", FIX)
        names = _header(path)
        self.tabular = "phi_0" not in names
        self.by_seed = "seed" in names  # independent recordings; else one dataset of episodes
        self.has_ratio, self.has_terminal = "ratio" in names, "terminal" in names
        units, n_states, agents = self._survey(names)
        self.q = n_states if self.tabular else sum(1 for c in names if c.startswith("phi_"))
        self.N = N = agents + 1
        self.units = sorted(units)
        self.lengths = np.array([units[u][1] + 1 for u in self.units])
        self.offsets = np.concatenate([[0], np.cumsum(self.lengths)])
        for u, T in zip(self.units, self.lengths):
            if units[u][0] != T * N:
                raise DgtdInputError(
                    f"{self._name(u)} does not hold every agent at every step 0..{T - 1} "
                    f"({units[u][0]:,} rows for {N} agents x {T:,} steps): one row per agent and "
                    "step is needed"
                )
        seeds = [k for k, _ in self.units]
        self.ids = np.unique(seeds)
        n_groups = min(GROUPS, len(self.units))
        self.groups = (
            [np.flatnonzero(np.array(seeds) == k) for k in self.ids]
            if self.by_seed
            else [np.arange(g, len(self.units), n_groups) for g in range(n_groups)]
        )
        if len(self.groups) < 2:
            raise DgtdInputError(
                f"transitions file {path} holds {len(self.groups)} "
                f"{'recording' if self.by_seed else 'episode'}; the reference's standard error needs "
                "at least two independent ones"
            )
        self._fill()

    def _survey(self, names: list[str]) -> tuple[dict, int, int]:
        """A first pass over the file's keys: {(seed, episode): (rows, last step)}, the number of states (tabular),
        the largest agent id."""
        firsts = [*KEYS, *(STATES if self.tabular else ())]
        units: dict = {}
        n_states, agents = 0, -1
        for batch in _read(self.path, [c for c in firsts if c in names]):
            b = _checked(self.path, batch, firsts)
            if min(b[c].min(initial=0) for c in firsts if c not in ("seed", "episode")) < 0:
                raise DgtdInputError(f"transitions file {self.path}: steps, agents and states are numbered from 0")
            if self.tabular:
                n_states = max(n_states, 1 + int(b["state"].max(initial=0)), 1 + int(b["next_state"].max(initial=0)))
            agents = max(agents, int(b["agent"].max(initial=-1)))
            keys, inverse = np.unique(np.stack([b["seed"], b["episode"]], axis=1), axis=0, return_inverse=True)
            inverse = inverse.ravel()
            count, last = np.bincount(inverse), np.full(len(keys), -1)
            np.maximum.at(last, inverse, b["step"])
            for (k, e), c, t in zip(keys.tolist(), count.tolist(), last.tolist()):
                n, before = units.get((k, e), (0, -1))
                units[(k, e)] = (n + c, max(before, t))
        return units, n_states, agents

    def _fill(self) -> None:
        """The second pass: every row into its cell (unit's step, agent) of a memory-mapped array, each cell once."""
        q, N, path = self.q, self.N, self.path
        self._dir = tempfile.mkdtemp(prefix="dgtd-transitions-")
        weakref.finalize(self, shutil.rmtree, self._dir, True)
        shape = (int(self.offsets[-1]), N, 2 * q + 3)
        self.rows = np.lib.format.open_memmap(Path(self._dir) / "rows.npy", "w+", np.float64, shape)
        seen = np.lib.format.open_memmap(Path(self._dir) / "seen.npy", "w+", np.bool_, shape[:2])
        index = {u: j for j, u in enumerate(self.units)}
        values = [
            *(STATES if self.tabular else (*(f"phi_{j}" for j in range(q)), *(f"next_phi_{j}" for j in range(q)))),
            "reward",
        ]
        extra = [*(["ratio"] if self.has_ratio else []), *(["terminal"] if self.has_terminal else [])]
        eye = np.eye(q) if self.tabular else np.zeros((0, 0))
        for batch in _read(path):
            b = _checked(path, batch, [*KEYS, *values, *extra])
            keys, inverse = np.unique(np.stack([b["seed"], b["episode"]], axis=1), axis=0, return_inverse=True)
            where = self.offsets[[index[tuple(key)] for key in keys.tolist()]][inverse.ravel()] + b["step"]
            block = np.empty((len(where), 2 * q + 3))
            if self.tabular:  # one-hot features of the state indices
                block[:, :q], block[:, q : 2 * q] = eye[b["state"]], eye[b["next_state"]]
                block[:, 2 * q] = b["reward"]
            else:
                block[:, : 2 * q + 1] = np.stack([b[name] for name in values], axis=1)
            block[:, -2] = b["ratio"] if self.has_ratio else 1.0
            block[:, -1] = 1.0 - b["terminal"] if self.has_terminal else 1.0
            self.rows[where, b["agent"]] = block
            seen[where, b["agent"]] = True
        for u, start, end in zip(self.units, self.offsets[:-1], self.offsets[1:]):
            if not seen[start:end].all():  # as many rows as cells, but some cell twice
                raise DgtdInputError(
                    f"{self._name(u)} does not hold every agent at every step 0..{end - start - 1}: "
                    "a row is repeated and another missing"
                )
        self.rows.flush()

    def _name(self, unit) -> str:
        k, e = unit
        return " ".join(
            ([f"recording {k}"] if self.by_seed else []) + ([f"episode {e}"] if not self.by_seed or e else [])
        )

    @property
    def recordings(self) -> int | None:
        """How many independent recordings (seeds of a run) the file holds; None for one dataset of episodes."""
        return len(self.ids) if self.by_seed else None

    def order(self, seed: int, k: int) -> np.ndarray:
        """The episodes seed id ``k`` replays, in order: recording k's, or when the file has no independent
        recordings every episode, sorted by a uniform keyed by (seed k, order, episode) (`dgtd.streams`)."""
        if self.by_seed:
            return self.groups[k]
        u = uniforms(np.uint64(seed_key(seed, k)), ORDER, 0, np.arange(len(self.units)))[0]
        return np.argsort(u, kind="stable")

    def steps(self, seed_ids) -> int:
        """How many steps a run over ``seed_ids`` can take: its shortest recording's, or every episode's."""
        if not self.by_seed:
            return int(self.offsets[-1])
        return int(min(self.lengths[self.groups[k]].sum() for k in seed_ids))

    def reference(self, gamma: float, name: str = "data", chunk: int = 4096):
        """The LSTD reference, one group per recording (or per eighth of the episodes, dealt in turn): M and A from
        every agent's transitions, b_i from agent i's (scaled by N, as each agent holds 1/N of the rows)."""
        from dgtd.problems.reference import MomentSums, TDCheck, estimate

        q, N = self.q, self.N
        sums, td = [], TDCheck(q)
        for group in self.groups:
            acc = MomentSums(N, q)
            for u in group:
                for t0 in range(self.offsets[u], self.offsets[u + 1], chunk):
                    x = np.asarray(self.rows[t0 : min(self.offsets[u + 1], t0 + chunk)]).reshape(-1, 2 * q + 3)
                    agent = np.tile(np.arange(N), len(x) // N)
                    R = np.zeros((len(x), N))
                    R[np.arange(len(x)), agent] = x[:, 2 * q] * N
                    acc.add(x[:, :q], x[:, q : 2 * q], R, gamma * x[:, -1], x[:, -2])
                    td.add(x[:, :q], x[:, q : 2 * q], x[:, 2 * q], gamma * x[:, -1], x[:, -2])  # every agent's rows
            sums.append(acc)
        return estimate(name, gamma, sums, off_policy=self.has_ratio, td_check=td)


class DataSource:
    """Blocks from recorded transitions: seed b replays the episodes of `TransitionFile.order` (seed, seed_ids[b]),
    each agent its own transition at every step (n = N); a block reads only its own rows of the file's disk-backed
    array. The recordings hold what the agents saw, not which of their links were up: those come from the run's
    ``network``, each edge up at each step by the uniform keyed by (seed k, edge up, edge, step), as a model's run
    draws them (`dgtd.streams`: the same links for seed k); without a network every link is up."""

    def __init__(self, data: TransitionFile, seed_ids=None, seed: int = 0, network=None):
        self.data, self.network = data, network
        self.chosen = list(range(data.recordings or 1)) if seed_ids is None else [int(k) for k in seed_ids]
        if data.recordings is not None and max(self.chosen) >= data.recordings:
            raise DgtdInputError(f"{data.path} holds {data.recordings} recordings; run at most {data.recordings} seeds")
        if network is not None and network.n_nodes != data.N:
            raise DgtdInputError(f"the network has {network.n_nodes} agents but {data.path} holds {data.N}")
        self.T, self.N, self.k = data.steps(self.chosen), data.N, 0
        # where each seed's stream is in the file's rows: its episodes' starts, in order, and where each ends in it
        orders = [data.order(seed, k) for k in self.chosen]
        self.starts = [data.offsets[o] for o in orders]
        self.ends = [np.cumsum(data.lengths[o]) for o in orders]
        self.keys = seed_keys(seed, self.chosen)

    def _positions(self, b: int, k: int, T: int) -> np.ndarray:
        """The rows of steps k .. k+T-1 of seed b's stream."""
        steps = np.arange(k, k + T)
        u = np.searchsorted(self.ends[b], steps, side="right")  # which episode of the stream holds each step
        before = np.where(u > 0, self.ends[b][np.maximum(u - 1, 0)], 0)
        return self.starts[b][u] + steps - before

    def start(self) -> None:
        self.k = 0

    def next_block(self, T: int) -> Block:
        if self.k + T > self.T:
            raise DgtdInputError(f"the recordings hold {self.T} steps; run at most that many iterations")
        q = self.data.q
        where = np.stack([self._positions(b, self.k, T) for b in range(len(self.chosen))], axis=1)  # (T, B)
        x = np.asarray(self.data.rows[where.ravel()]).reshape(*where.shape, self.N, 2 * q + 3)
        self.k += T
        B, N = len(self.chosen), self.N
        M = T * B * N
        index = np.arange(M).reshape(T, B, N)
        table = SampleTable(
            np.concatenate([x[..., :q].reshape(M, q), x[..., q : 2 * q].reshape(M, q)]),
            np.concatenate([x[..., -2].ravel(), np.ones(M)])[:, None],
            np.concatenate([np.ones(M), x[..., -1].ravel()]),
        )
        return Block(index, np.zeros_like(index), index + M, np.ascontiguousarray(x[..., 2 * q]), self._links(T), table)

    def _links(self, T: int):
        """The edges up at each of the next T steps (T, B, E), or None when every edge is always up."""
        if self.network is None or self.network.fixed:
            return None
        steps = (self.k - T + np.arange(T, dtype=np.uint64))[:, None, None]  # (next_block has moved k on)
        u = edge_uniforms(self.keys, steps, self.network.base.edges)
        return u < self.network.p

    def get_state(self) -> dict:
        return {"k": self.k}

    def set_state(self, state: dict) -> None:
        self.k = int(state["k"])
