"""Samples from recorded transitions: offline distributed evaluation on a table of what the agents saw.

A table (Parquet, CSV or .npz of columns) holds one row per agent and step:

- ``seed`` (or ``episode``): which independent recording the row belongs to (a run's seed, an independent copy);
- ``step``: its time index within that recording; ``agent``: 0 .. N-1;
- the state: feature columns ``phi_0 .. phi_{q-1}`` and ``next_phi_0 ..`` of the next state, or integer columns
  ``state`` and ``next_state`` (0 .. S-1), whose features are then tabular (one-hot, q = S);
- ``reward``: the agent's own reward; optional ``ratio`` (importance ratio, 1 if absent) and ``terminal`` (1 where
  the transition ended an episode: its TD target is the reward alone).

Every recording must hold every agent at every step from 0 on; recording k (in the order of their ids) is seed k of
a run, and the reference is LSTD over the recordings (`dgtd.problems.reference`), its standard error from their
spread. `TransitionFile` reads the file in batches (Parquet and CSV stream; an .npz is read whole) into a
disk-backed array ordered by step, so that a file larger than memory works and each block of a run is one slice.
"""

from __future__ import annotations

import shutil
import tempfile
import weakref
from pathlib import Path

import numpy as np

from dgtd.errors import DgtdInputError
from dgtd.samples import Block, SampleTable

KEYS = ("seed", "step", "agent")
STATES = ("state", "next_state")  # tabular states, instead of feature columns
FIX = ("give one row per agent and step with columns seed, step, agent, phi_0.., next_phi_0.. (or state, "
       "next_state), reward")
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
        with np.load(path, allow_pickle=False) as z:
            yield {k: z[k] for k in z.files if columns is None or k in columns}
    else:
        raise DgtdInputError(f"transitions file {path}: give a .parquet, .csv or .npz file")


def _read(path: Path, columns=None):
    try:
        yield from _batches(path, columns)
    except DgtdInputError:
        raise
    except ImportError:
        raise DgtdInputError(f"reading {path.suffix} files needs pyarrow: pip install 'dgtd[parquet]' (or give an "
                             ".npz of the same columns)") from None
    except Exception as e:  # noqa: BLE001  (a reader's own error: a damaged or foreign file)
        raise DgtdInputError(f"transitions file {path} cannot be read ({type(e).__name__}: {e}); {FIX}") from None


def _header(path: Path) -> list[str]:
    """The column names (``episode`` standing for ``seed``), checked: the keys, reward and phi_j / next_phi_j (or
    state and next_state)."""
    for batch in _read(path):
        names = list(batch)
        break
    else:
        names = []
    names = ["seed" if n == "episode" and "seed" not in names else n for n in names]
    states = ("state", "next_state") if "state" in names and "phi_0" not in names else ("phi_0", "next_phi_0")
    missing = [c for c in (*KEYS, "reward", *states) if c not in names]
    if missing:
        raise DgtdInputError(f"transitions file {path} lacks the column(s) {', '.join(missing)}; {FIX}")
    q = sum(1 for c in names if c.startswith("phi_"))
    if sorted((c for c in names if c.startswith("phi_")), key=lambda c: int(c[4:]) if c[4:].isdigit() else -1) \
            != [f"phi_{j}" for j in range(q)] or any(f"next_phi_{j}" not in names for j in range(q)):
        raise DgtdInputError(f"transitions file {path}: the feature columns must be phi_0 .. phi_{q - 1} and "
                             f"next_phi_0 .. next_phi_{q - 1}")
    return names


def _checked(path: Path, batch: dict, names) -> dict:
    """A batch's columns as int64 keys and float64 values, or a one-line error naming the column."""
    if "seed" not in batch and "episode" in batch:
        batch["seed"] = batch.pop("episode")
    out = {}
    for name in names:
        x = np.asarray(batch[name])
        if name in KEYS or name in STATES:
            try:
                out[name] = x.astype(np.int64, casting="safe")
            except TypeError:
                raise DgtdInputError(f"transitions file {path}: column {name} must hold integers, got {x.dtype}") from None
        else:
            if x.dtype.kind not in "biuf" or not np.isfinite(x.astype(np.float64)).all():
                raise DgtdInputError(f"transitions file {path}: column {name} must hold finite numbers")
            out[name] = x.astype(np.float64)
    return out


class TransitionFile:
    """A transitions table read in two passes: the recordings' ids, lengths and agents, then every row into a
    disk-backed array ``rows`` (T, recordings, N, 2q + 3) of phi, next phi, reward, ratio and continuing, in a
    temporary directory removed with this object."""

    def __init__(self, path):
        self.path = path = Path(path)
        if not path.is_file():
            raise DgtdInputError(f"transitions file {path} is missing; {FIX}")
        names = _header(path)
        self.tabular = "phi_0" not in names
        self.has_ratio, self.has_terminal = "ratio" in names, "terminal" in names
        keys, n_states = {}, 0
        firsts = [*KEYS, *(STATES if self.tabular else ())]
        for batch in _read(path, firsts if "episode" not in names else None):
            b = _checked(path, batch, firsts)
            if min(b[c].min(initial=0) for c in firsts if c != "seed") < 0:
                raise DgtdInputError(f"transitions file {path}: steps, agents and states are numbered from 0")
            if self.tabular:
                n_states = max(n_states, 1 + int(b["state"].max(initial=0)), 1 + int(b["next_state"].max(initial=0)))
            for k in np.unique(b["seed"]):
                rows = b["seed"] == k
                n, last, agents = keys.get(int(k), (0, -1, -1))
                keys[int(k)] = (n + int(rows.sum()), max(last, int(b["step"][rows].max())),
                                max(agents, int(b["agent"][rows].max())))
        if len(keys) < 2:
            raise DgtdInputError(f"transitions file {path} holds {len(keys)} recording(s); the reference's standard "
                                 "error needs at least two independent ones (seed or episode column)")
        self.q = q = n_states if self.tabular else sum(1 for c in names if c.startswith("phi_"))
        self.ids = np.array(sorted(keys))
        self.N = N = max(a for _, _, a in keys.values()) + 1
        self.lengths = np.array([keys[k][1] + 1 for k in self.ids])
        for k, T in zip(self.ids, self.lengths):
            if keys[k][0] != T * N:
                raise DgtdInputError(f"recording {k} does not hold every agent at every step 0..{T - 1} ({keys[k][0]:,} "
                                     f"rows for {N} agents x {T:,} steps): one row per agent and step is needed")
        self._dir = tempfile.mkdtemp(prefix="dgtd-transitions-")
        weakref.finalize(self, shutil.rmtree, self._dir, True)
        shape = (int(self.lengths.max()), len(self.ids), N, 2 * q + 3)
        self.rows = np.lib.format.open_memmap(Path(self._dir) / "rows.npy", "w+", np.float64, shape)
        seen = np.lib.format.open_memmap(Path(self._dir) / "seen.npy", "w+", np.bool_, shape[:3])
        index = {int(k): b for b, k in enumerate(self.ids)}
        values = [*(STATES if self.tabular else (*(f"phi_{j}" for j in range(q)), *(f"next_phi_{j}" for j in range(q)))),
                  "reward"]
        eye = np.eye(q) if self.tabular else None
        for batch in _read(path):
            b = _checked(path, batch, [*KEYS, *values, *(["ratio"] if self.has_ratio else []),
                                       *(["terminal"] if self.has_terminal else [])])
            t, r, i = b["step"], np.array([index[int(k)] for k in b["seed"]]), b["agent"]
            block = np.empty((len(t), 2 * q + 3))
            if self.tabular:  # one-hot features of the state indices
                block[:, :q], block[:, q: 2 * q] = eye[b["state"]], eye[b["next_state"]]
                block[:, 2 * q] = b["reward"]
            else:
                block[:, : 2 * q + 1] = np.stack([b[name] for name in values], axis=1)
            block[:, -2] = b["ratio"] if self.has_ratio else 1.0
            block[:, -1] = 1.0 - b["terminal"] if self.has_terminal else 1.0
            self.rows[t, r, i] = block
            seen[t, r, i] = True
        for b, (k, T) in enumerate(zip(self.ids, self.lengths)):
            if not seen[:T, b].all():  # as many rows as cells, but some cell twice
                raise DgtdInputError(f"recording {k} does not hold every agent at every step 0..{T - 1}: a row is "
                                     "repeated and another missing")
        self.rows.flush()

    @property
    def recordings(self) -> int:
        return len(self.ids)

    def steps(self, seed_ids) -> int:
        """How many steps a run over recordings ``seed_ids`` can take: the shortest of them."""
        return int(self.lengths[list(seed_ids)].min())

    def reference(self, gamma: float, name: str = "data", chunk: int = 4096):
        """The LSTD reference over every recording, one group per recording: M and A from every agent's transitions,
        b_i from agent i's (scaled by N, as each agent holds 1/N of the rows)."""
        from dgtd.problems.reference import MomentSums, TDCheck, estimate

        q, N = self.q, self.N
        sums, td = [], TDCheck(q)
        for b, T in enumerate(self.lengths):
            acc = MomentSums(N, q)
            for t0 in range(0, T, chunk):
                x = np.asarray(self.rows[t0: min(T, t0 + chunk), b]).reshape(-1, 2 * q + 3)
                agent = np.tile(np.arange(N), len(x) // N)
                R = np.zeros((len(x), N))
                R[np.arange(len(x)), agent] = x[:, 2 * q] * N
                acc.add(x[:, :q], x[:, q: 2 * q], R, gamma * x[:, -1], x[:, -2])
                td.add(x[:, :q], x[:, q: 2 * q], x[:, 2 * q], gamma * x[:, -1], x[:, -2])  # every agent's transitions
            sums.append(acc)
        return estimate(name, gamma, sums, off_policy=self.has_ratio, td_check=td)


class DataSource:
    """Blocks from recorded transitions: recording ``seed_ids[b]`` is seed b, each agent its own transition at every
    step (n = N); a block reads only its steps' slice of the file's disk-backed rows."""

    def __init__(self, data: TransitionFile, seed_ids=None):
        self.data = data
        self.chosen = list(range(data.recordings)) if seed_ids is None else [int(k) for k in seed_ids]
        if max(self.chosen) >= data.recordings:
            raise DgtdInputError(f"{data.path} holds {data.recordings} recordings; run at most {data.recordings} seeds")
        self.T, self.N, self.k = data.steps(self.chosen), data.N, 0

    def start(self) -> None:
        self.k = 0

    def next_block(self, T: int) -> Block:
        if self.k + T > self.T:
            raise DgtdInputError(f"the recordings hold {self.T} steps; run at most that many iterations")
        q = self.data.q
        x = np.asarray(self.data.rows[self.k: self.k + T][:, self.chosen])  # (T, B, N, 2q + 3)
        self.k += T
        B, N = len(self.chosen), self.N
        M = T * B * N
        index = np.arange(M).reshape(T, B, N)
        table = SampleTable(np.concatenate([x[..., :q].reshape(M, q), x[..., q: 2 * q].reshape(M, q)]),
                            np.concatenate([x[..., -2].ravel(), np.ones(M)])[:, None],
                            np.concatenate([np.ones(M), x[..., -1].ravel()]))
        return Block(index, np.zeros_like(index), index + M, np.ascontiguousarray(x[..., 2 * q]), None, table)

    def get_state(self) -> dict:
        return {"k": self.k}

    def set_state(self, state: dict) -> None:
        self.k = int(state["k"])
