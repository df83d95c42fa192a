"""Samples from recorded transitions: offline distributed evaluation on a table of what the agents saw.

A table (Parquet, CSV or .npz of columns) holds one row per agent and step:

- ``seed`` (or ``episode``): which independent recording the row belongs to (a run's seed, an independent copy);
- ``step``: its time index within that recording; ``agent``: 0 .. N-1;
- the state: feature columns ``phi_0 .. phi_{q-1}`` and ``next_phi_0 ..`` of the next state;
- ``reward``: the agent's own reward; optional ``ratio`` (importance ratio, 1 if absent) and ``terminal`` (1 where
  the transition ended an episode: its TD target is the reward alone).

Every recording must hold every agent at every step from 0 on; each recording becomes one seed of the run, and the
reference is LSTD over the recordings (`dgtd.problems.reference`), its standard error from their spread.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dgtd.errors import DgtdInputError
from dgtd.samples import Block, SampleTable

REQUIRED = ("step", "agent", "reward")


def read_transitions(path) -> dict:
    """The columns of a transitions table as arrays, checked; every problem is one line naming the file."""
    path = Path(path)
    fix = "give one row per agent and step with columns seed, step, agent, phi_0.., next_phi_0.., reward"
    if not path.is_file():
        raise DgtdInputError(f"transitions file {path} is missing; {fix}")
    try:
        if path.suffix == ".parquet":
            import pyarrow.parquet as pq

            table = pq.read_table(path)
            cols = {name: table.column(name).to_numpy() for name in table.column_names}
        elif path.suffix == ".csv":
            import pyarrow.csv as pcsv

            table = pcsv.read_csv(path)
            cols = {name: table.column(name).to_numpy() for name in table.column_names}
        elif path.suffix == ".npz":
            with np.load(path, allow_pickle=False) as z:
                cols = {k: z[k] for k in z.files}
        else:
            raise DgtdInputError(f"transitions file {path}: give a .parquet, .csv or .npz file")
    except DgtdInputError:
        raise
    except Exception as e:  # noqa: BLE001  (a reader's own error: a damaged or foreign file)
        raise DgtdInputError(f"transitions file {path} cannot be read ({type(e).__name__}: {e}); {fix}") from None
    if "seed" not in cols and "episode" in cols:
        cols["seed"] = cols["episode"]
    missing = [c for c in (*REQUIRED, "seed", "phi_0", "next_phi_0") if c not in cols]
    if missing:
        raise DgtdInputError(f"transitions file {path} lacks the column(s) {', '.join(missing)}; {fix}")
    q = sum(1 for c in cols if c.startswith("phi_"))
    if [f"phi_{j}" for j in range(q)] != sorted((c for c in cols if c.startswith("phi_")), key=lambda c: int(c[4:])) \
            or any(f"next_phi_{j}" not in cols for j in range(q)):
        raise DgtdInputError(f"transitions file {path}: the feature columns must be phi_0 .. phi_{q - 1} and "
                             f"next_phi_0 .. next_phi_{q - 1}")
    out = {}
    for name in ("seed", "step", "agent"):
        try:
            out[name] = np.asarray(cols[name]).astype(np.int64, casting="safe")
        except TypeError:
            raise DgtdInputError(f"transitions file {path}: column {name} must hold integers, got "
                                 f"{np.asarray(cols[name]).dtype}") from None
    for name in ("reward", "ratio", "terminal", *(f"phi_{j}" for j in range(q)), *(f"next_phi_{j}" for j in range(q))):
        if name in cols:
            x = np.asarray(cols[name])
            if x.dtype.kind not in "biuf" or not np.isfinite(x.astype(np.float64)).all():
                raise DgtdInputError(f"transitions file {path}: column {name} must hold finite numbers")
            out[name] = x.astype(np.float64)
    out["phi"] = np.stack([out.pop(f"phi_{j}") for j in range(q)], axis=1)
    out["next_phi"] = np.stack([out.pop(f"next_phi_{j}") for j in range(q)], axis=1)
    return out


class DataSource:
    """Blocks from recorded transitions: recording k is seed k (in the order of their ids), each agent its own
    transition at every step (n = N)."""

    def __init__(self, columns: dict, seed_ids=None):
        seeds = np.unique(columns["seed"])
        chosen = seeds if seed_ids is None else seeds[list(seed_ids)]
        agents = np.unique(columns["agent"])
        self.N = len(agents)
        if not np.array_equal(agents, np.arange(self.N)):
            raise DgtdInputError(f"agents must be numbered 0 .. N-1, got {agents[:10].tolist()}")
        steps = {int(k): np.sum(columns["seed"] == k) // self.N for k in chosen}
        self.T = min(steps.values())
        B, N, T = len(chosen), self.N, self.T
        q = columns["phi"].shape[1]
        self.phi = np.empty((T, B, N, q))
        self.next_phi = np.empty((T, B, N, q))
        self.r, self.ratio, self.cont = np.empty((T, B, N)), np.ones((T, B, N)), np.ones((T, B, N))
        for b, k in enumerate(chosen):
            rows = np.flatnonzero((columns["seed"] == k) & (columns["step"] < T))
            t, i = columns["step"][rows], columns["agent"][rows]
            grid = np.zeros((T, N), bool)
            grid[t, i] = True
            if len(rows) != T * N or not grid.all():
                raise DgtdInputError(f"recording {k} does not hold every agent at every step 0..{T - 1}: one row per "
                                     "agent and step is needed")
            self.phi[t, b, i], self.next_phi[t, b, i] = columns["phi"][rows], columns["next_phi"][rows]
            self.r[t, b, i] = columns["reward"][rows]
            if "ratio" in columns:
                self.ratio[t, b, i] = columns["ratio"][rows]
            if "terminal" in columns:
                self.cont[t, b, i] = 1.0 - columns["terminal"][rows]
        self.k = 0

    def start(self) -> None:
        self.k = 0

    def next_block(self, T: int) -> Block:
        if self.k + T > self.T:
            raise DgtdInputError(f"the recordings hold {self.T} steps; run at most that many iterations")
        sl = slice(self.k, self.k + T)
        self.k += T
        B, N = self.phi.shape[1], self.N
        M = T * B * N
        index = np.arange(M).reshape(T, B, N)
        table = SampleTable(np.concatenate([self.phi[sl].reshape(M, -1), self.next_phi[sl].reshape(M, -1)]),
                            np.concatenate([self.ratio[sl].ravel(), np.ones(M)])[:, None],
                            np.concatenate([np.ones(M), self.cont[sl].ravel()]))
        return Block(index, np.zeros_like(index), index + M, self.r[sl], None, table)

    def get_state(self) -> dict:
        return {"k": self.k}

    def set_state(self, state: dict) -> None:
        self.k = int(state["k"])


def reference_from_data(columns: dict, gamma: float, name: str = "data"):
    """The LSTD reference over every recording, one group per recording (at least two)."""
    from dgtd.problems.reference import MomentSums, estimate

    seeds = np.unique(columns["seed"])
    N = len(np.unique(columns["agent"]))
    q = columns["phi"].shape[1]
    sums = []
    for k in seeds:
        rows = columns["seed"] == k
        acc = MomentSums(N, q)
        phi, nphi, agent = columns["phi"][rows], columns["next_phi"][rows], columns["agent"][rows]
        R = np.zeros((rows.sum(), N))
        R[np.arange(rows.sum()), agent] = columns["reward"][rows] * N  # agent i's reward counts in b_i only
        cont = 1.0 - columns.get("terminal", np.zeros(len(rows)))[rows]
        ratio = columns.get("ratio", np.ones(len(rows)))[rows]
        acc.add(phi, nphi, R, gamma * cont, ratio)
        sums.append(acc)
    return estimate(name, gamma, sums)
