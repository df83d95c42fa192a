"""How long and how many: a run's settings (`RunSettings`), the only defaults of these fields in dgtd, and the step
counts derived from them (checkpoints, blocks)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from dgtd.errors import DgtdInputError
from dgtd.fields import option

BACKENDS = ("numpy", "numba", "jax")


@dataclass(frozen=True)
class RunSettings:
    """How long and how many: the only defaults of these fields in dgtd (`dgtd.config.RunLength`, the CLI and
    `dgtd compare` take theirs from here).

    - ``iterations`` T, ``seeds`` B run side by side, base ``seed`` (seed k draws with key (seed, k), `dgtd.streams`);
    - ``checkpoints``: about how many times metrics are recorded (`checkpoint_steps`);
    - ``tail_fraction``: the final fraction of the run averaged for w_tail;
    - ``block_size``: steps drawn and advanced per block (no effect on results);
    - ``backend``: one of `BACKENDS`, the compiled kernels, the NumPy reference or JAX (`dgtd.backends.jax`);
    - ``asynchronous``: agents spread over the ranks of an mpiexec job use the newest messages received from the
      other ranks, waiting only when the newest is more than ``staleness`` steps old (None: never; 0: the
      synchronous numbers) (`dgtd.backends.mailbox`); off, the ranks give one process's numbers bit for bit.
    """

    iterations: int = field(
        default=10_000,
        metadata=option("Number of iterations T (default: the scenario's).", flags=("--iterations", "-T")),
    )
    seeds: int = field(default=1, metadata=option("Independent runs, side by side."))
    seed: int = field(default=0, metadata=option("Base seed; seed k draws from the keyed streams of key (seed, k)."))
    checkpoints: int = field(
        default=200, metadata=option("How many times to record metrics (at most once per iteration).")
    )
    tail_fraction: float = field(default=0.5, metadata=option("Final fraction of the run averaged for w_tail."))
    block_size: int = field(default=4096, metadata=option("Steps drawn and advanced per block (no effect on results)."))
    backend: str = field(
        default="numba",
        metadata=option(
            "The compiled kernels (numba), the NumPy reference, or JAX on its device (the extra dgtd[jax]; perfect "
            "and lossy links): the same numbers."
        ),
    )
    asynchronous: bool = field(
        default=False,
        metadata=option(
            "Under mpiexec: ranks do not wait for each other's messages, each agent using the newest received (their "
            "ages are recorded); synchronous (the default) gives one process's numbers.",
            flags=("--asynchronous/--synchronous",),
        ),
    )
    staleness: int | None = field(
        default=None,
        metadata=option(
            "With --asynchronous: a rank waits for a neighbour's message once the newest it has is more than S steps "
            "old (default: never waits; 0: the synchronous numbers)."
        ),
    )

    def __post_init__(self):
        for name in ("iterations", "seeds", "checkpoints", "block_size"):
            object.__setattr__(self, name, check_count(name, getattr(self, name), 1))
        object.__setattr__(self, "seed", check_count("seed", self.seed, 0))
        if self.staleness is not None:
            object.__setattr__(self, "staleness", check_count("staleness", self.staleness, 0))
            if not self.asynchronous:
                raise DgtdInputError("staleness bounds the ages of an asynchronous run's messages: give --asynchronous")
        if not 0.0 < self.tail_fraction <= 1.0:
            raise DgtdInputError(f"tail_fraction must lie in (0, 1], got {self.tail_fraction}")
        if self.backend not in BACKENDS:
            raise DgtdInputError(f"backend must be one of {', '.join(BACKENDS)}, got {self.backend!r}")


MAX_COUNT = 2**63 - 1  # what a 64-bit integer (NumPy's, TOML's) holds


def check_count(name: str, value: Any, low: int) -> int:
    """An integer setting in [low, 2^63 - 1] as an int (a whole float such as 1e5 too), or a one-line error naming
    it."""
    if isinstance(value, (float, np.floating)) and float(value).is_integer() and abs(float(value)) < 2.0**63:
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not low <= value <= MAX_COUNT:
        raise DgtdInputError(f"{name} must be >= {low} and below 2^63, a whole number; got {value!r}")
    return int(value)


def checkpoint_steps(T: int, n: int) -> np.ndarray:
    """About n steps in 1..T, half evenly spaced and half log-spaced (for linear and log plots), T included. Any n
    from 2T on gives every step once, so n is capped there (a huge n would allocate for nothing)."""
    n = min(n, 2 * T)
    lin = np.linspace(0, T, n // 2 + 1)[1:]
    log = np.geomspace(1, T, n - n // 2)
    return np.unique(np.concatenate([np.round(lin), np.round(log), [T]]).astype(np.int64).clip(1, T))


def kept_steps(steps: np.ndarray, T: int, resume: dict | None) -> np.ndarray:
    """The steps a run of T measures at, ``steps`` where it starts afresh; a resumed run's those its checkpoint kept,
    and where that ended before T (a finished run extended to more steps), the ones of ``steps`` beyond its end."""
    if resume is None or resume.get("steps") is None:  # (a fresh run, or a checkpoint older than its steps)
        return steps
    kept = np.asarray(resume["steps"], dtype=np.int64)
    return np.concatenate([kept, steps[steps > kept[-1]]]) if kept[-1] < T else kept


def tail_steps(T: int, tail_fraction: float) -> int:
    """The steps of a run of T that the tail average takes (its last ``tail_fraction``, at least one)."""
    return max(1, int(np.ceil(tail_fraction * T)))


def tail_blocker(T1: int, T2: int, tail_fraction: float) -> str:
    """Why a run that ended at T1 cannot be extended to T2 for its tail average ('' where it can): the tail of a run
    of T2 steps begins before T1, at a step whose running sum the run did not keep (unless it is the one its own tail
    began at)."""
    start = T2 - tail_steps(T2, tail_fraction)
    if start >= T1 or start == T1 - tail_steps(T1, tail_fraction):
        return ""
    least = max(T2, int(T1 / (1.0 - tail_fraction)) - 2)  # (f < 1 here: a tail of the whole run begins at 0)
    while least - tail_steps(least, tail_fraction) < T1:
        least += 1
    return (
        f"its tail average (the last {tail_fraction:g} of the run) would begin at step {start:,}, before its end, "
        f"where the running sum it needs was not kept; give -T {least} or more"
    )


def block_steps(block_size: int, n_agents: int, n_edges: int, n_seeds: int, budget: int = 1 << 21) -> int:
    """Steps per block: at most ``block_size``, and few enough that a block's samples stay near ``budget``
    numbers (tens of MB), whatever N and |E|. Results do not depend on it."""
    per_step = n_seeds * (4 * n_agents + n_edges)
    return int(max(1, min(int(block_size), budget // max(per_step, 1))))
