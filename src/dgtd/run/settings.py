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


def block_steps(block_size: int, n_agents: int, n_edges: int, n_seeds: int, budget: int = 1 << 21) -> int:
    """Steps per block: at most ``block_size``, and few enough that a block's samples stay near ``budget``
    numbers (tens of MB), whatever N and |E|. Results do not depend on it."""
    per_step = n_seeds * (4 * n_agents + n_edges)
    return int(max(1, min(int(block_size), budget // max(per_step, 1))))
