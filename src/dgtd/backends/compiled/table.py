"""A table of values over configurations too many to index densely (an agent's critic over its kappa-hop
neighbourhood's states and actions, `dgtd.run.scalable`): each configuration's 64-bit fingerprint is given a row the
first time it is met (open addressing, linear probing, compiled), the rows' values held in one array. Rows are given
in the order configurations are first met, so the values are a pure function of what was met, whatever the table's
size. Two configurations share a row only where their fingerprints collide: about n^2 / 2^65 for n of them (under
3e-5 at 3 x 10^7)."""

from __future__ import annotations

import numpy as np
from numba import njit

EMPTY = np.uint64(0)  # a slot no fingerprint holds (fingerprints are made odd: never 0)


@njit(cache=True)
def _rows(slots, rows, fingerprints, count):
    """The row of each fingerprint (flat), a new one (count, count + 1, ...) where it is met first; the count after."""
    out = np.empty(fingerprints.size, dtype=np.int64)
    mask = np.uint64(slots.size - 1)
    for n in range(fingerprints.size):
        f = fingerprints[n]
        j = f & mask
        while True:
            if slots[j] == f:
                out[n] = rows[j]
                break
            if slots[j] == EMPTY:
                slots[j], rows[j] = f, count
                out[n] = count
                count += 1
                break
            j = (j + np.uint64(1)) & mask
    return out, count


class FingerprintTable:
    """Rows for fingerprints (`rows`), and their values (`values`, 0 where new), growing as needed."""

    def __init__(self, capacity: int = 1 << 12):
        self.slots = np.zeros(capacity, dtype=np.uint64)
        self.rows_of = np.zeros(capacity, dtype=np.int64)
        self.count = 0
        self.values = np.zeros(capacity // 2)

    def rows(self, fingerprints: np.ndarray) -> np.ndarray:
        """The rows of ``fingerprints`` (any shape, uint64, odd), new rows' values 0."""
        flat = np.ascontiguousarray(fingerprints, dtype=np.uint64).ravel()
        while 2 * (self.count + flat.size) > self.slots.size:  # (at most half full: short probes)
            self._grow()
        out, self.count = _rows(self.slots, self.rows_of, flat, self.count)
        if self.count > self.values.size:
            grown = np.zeros(max(self.count, 2 * self.values.size))
            grown[: self.values.size] = self.values
            self.values = grown
        return out.reshape(fingerprints.shape)

    def _grow(self) -> None:
        held = self.slots != EMPTY
        keys, rows = self.slots[held], self.rows_of[held]
        self.slots = np.zeros(2 * self.slots.size, dtype=np.uint64)
        self.rows_of = np.zeros(self.slots.size, dtype=np.int64)
        _place(self.slots, self.rows_of, keys, rows)

    def state(self) -> dict:
        """What a checkpoint keeps of the table (`restored` makes it again)."""
        return {"slots": self.slots, "rows": self.rows_of, "values": self.values[: self.count], "count": self.count}

    @classmethod
    def restored(cls, state: dict) -> FingerprintTable:
        table = cls(capacity=int(np.asarray(state["slots"]).size))
        table.slots, table.rows_of = np.array(state["slots"], dtype=np.uint64), np.array(state["rows"], dtype=np.int64)
        table.count = int(state["count"])
        table.values = np.zeros(max(table.slots.size // 2, table.count))
        table.values[: table.count] = state["values"]
        return table

    @property
    def nbytes(self) -> int:
        return self.slots.nbytes + self.rows_of.nbytes + self.values.nbytes


@njit(cache=True)
def _place(slots, rows, fingerprints, given):
    """Fingerprints not yet in the table put in it with the rows ``given``."""
    mask = np.uint64(slots.size - 1)
    for n in range(fingerprints.size):
        j = fingerprints[n] & mask
        while slots[j] != EMPTY:
            j = (j + np.uint64(1)) & mask
        slots[j], rows[j] = fingerprints[n], given[n]


_M = np.uint64(0x9E3779B97F4A7C15)


def fingerprints(owner: np.ndarray, digits: np.ndarray) -> np.ndarray:
    """Odd 64-bit fingerprints of (``owner``, ``digits``...) along the last axis of ``digits`` (..., K) (int64, -1 for
    a padding member), ``owner`` broadcast against its leading axes: a splitmix64 chain, one round a digit."""
    with np.errstate(over="ignore"):
        h = np.asarray(owner, dtype=np.uint64) * _M + np.uint64(0x632BE59BD9B4E019)
        for k in range(digits.shape[-1]):
            h = _mix(h ^ (digits[..., k].astype(np.uint64) + np.uint64(k + 2) * _M))
    return h | np.uint64(1)


def _mix(z):
    """splitmix64's finaliser (Steele, Lea and Flood 2014)."""
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))
