"""The keyed streams (`dgtd.streams`) inside compiled kernels: the same Philox-4x32-10 function, compiled, and the
doubles it gives, drawn where they are used: a kernel needs only each seed's key and the step, never a stream's
position, so its draws do not depend on the order it makes them in (threads, layouts and ranks agree)."""

from __future__ import annotations

import numpy as np
from numba import njit

from dgtd.streams import philox4x32

_philox = njit(cache=True, inline="always")(philox4x32)
_LOW = np.uint64(0xFFFFFFFF)
_32 = np.uint64(32)
_11 = np.uint64(11)
_24 = np.uint64(24)
_TO_UNIT = 1.0 / 9007199254740992.0  # 2^-53


@njit(cache=True, inline="always")
def keyed_pair(key, purpose, step, entity, index):
    """`dgtd.streams.uniforms` for one (key, purpose, step, entity, index): the two doubles, bit for bit."""
    step, entity = np.uint64(step), np.uint64(entity)
    tag = (np.uint64(purpose) << _24) | np.uint64(index)
    x0, x1, x2, x3 = _philox(step & _LOW, step >> _32, entity, tag, key & _LOW, key >> _32)
    # the top 53 bits through int64 (they fit): one conversion instruction, where uint64 takes several
    u0 = np.float64(np.int64(((x1 << _32) | x0) >> _11)) * _TO_UNIT
    u1 = np.float64(np.int64(((x3 << _32) | x2) >> _11)) * _TO_UNIT
    return u0, u1


@njit(cache=True)
def keyed_pairs(key, purpose, step, entity, index, out0, out1):
    """`keyed_pair` over arrays of equal length (a test's and a benchmark's loop)."""
    for n in range(out0.shape[0]):
        out0[n], out1[n] = keyed_pair(key[n], purpose, step[n], entity[n], index[n])
