"""NumPy's PCG64 stream inside compiled kernels: the same uniforms as ``Generator.random()``, drawn where
they are used instead of being materialised in blocks.

NumPy's PCG64 is the 128-bit LCG state <- state * M + inc followed by the XSL-RR output; ``random()`` keeps
the top 53 bits of each 64-bit output. A kernel holds the state of each stream as four uint64 words
(state high, state low, increment high, increment low), read from and written back to the Python
``Generator`` around each block (`pcg_words`, `set_pcg_words`), so checkpoints, resumes and the NumPy
reference see exactly the stream they would have seen.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

_MASK64 = (1 << 64) - 1
_M_HI = np.uint64(2549297995355413924)  # PCG_DEFAULT_MULTIPLIER_128 = 2^64 * _M_HI + _M_LO
_M_LO = np.uint64(4865540595714422341)
_SHIFT_ROT = np.uint64(58)
_SHIFT_53 = np.uint64(11)
_ROT_MASK = np.uint64(63)
_ONE = np.uint64(1)
_ZERO = np.uint64(0)
_TO_UNIT = 1.0 / 9007199254740992.0  # 2^-53


@intrinsic
def _mulhi(typingctx, a, b):
    """High 64 bits of the 128-bit product of two uint64 (one machine multiply)."""
    sig = types.uint64(types.uint64, types.uint64)

    def codegen(context, builder, signature, args):
        i128 = ir.IntType(128)
        p = builder.mul(builder.zext(args[0], i128), builder.zext(args[1], i128))
        return builder.trunc(builder.lshr(p, ir.Constant(i128, 64)), ir.IntType(64))

    return sig, codegen


@njit(cache=True, inline="always")
def pcg_step(hi, lo, inc_hi, inc_lo):
    """One step of a PCG64 stream: (state hi, state lo, uniform in [0, 1)), the state as four uint64 words
    (state hi, state lo, increment hi, increment lo). A loop of draws keeps the state in registers and writes it
    back once: written back after every draw, it would put a store and a load on the chain between draws."""
    # state * M + inc, modulo 2^128
    lo_m = lo * _M_LO
    hi_m = _mulhi(lo, _M_LO) + lo * _M_HI + hi * _M_LO
    lo_n = lo_m + inc_lo
    hi_n = hi_m + inc_hi + (_ONE if lo_n < lo_m else _ZERO)
    # XSL-RR output: (hi ^ lo) rotated right by the top 6 bits of the state
    x = hi_n ^ lo_n
    rot = hi_n >> _SHIFT_ROT
    out = (x >> rot) | (x << ((_ZERO - rot) & _ROT_MASK))
    # the top 53 bits, through int64 (they fit): one conversion instruction, where uint64 takes several
    return hi_n, lo_n, np.float64(np.int64(out >> _SHIFT_53)) * _TO_UNIT


def pcg_words(generators) -> np.ndarray:
    """(len, 4) uint64 words of the PCG64 states of ``generators`` (NumPy Generators on PCG64)."""
    out = np.empty((len(generators), 4), np.uint64)
    for n, g in enumerate(generators):
        st = g.bit_generator.state
        if st["bit_generator"] != "PCG64":
            raise TypeError(f"compiled sampling needs PCG64 streams, got {st['bit_generator']}")
        s, inc = st["state"]["state"], st["state"]["inc"]
        out[n] = (s >> 64, s & _MASK64, inc >> 64, inc & _MASK64)
    return out


def set_pcg_words(generators, words: np.ndarray) -> None:
    """Write states advanced by a kernel back into ``generators``."""
    for g, w in zip(generators, words, strict=True):
        st = g.bit_generator.state
        st["state"]["state"] = (int(w[0]) << 64) | int(w[1])
        g.bit_generator.state = st
