"""Centralised TDC, its one learner's step: `dgtd.algorithms.tdc.TDC.update`, line for line (GTD2's with TDC's value
terms: `dgtd.backends.compiled.steps.gtd2.centralised`)."""

from __future__ import annotations

from typing import NamedTuple

from numba import njit

from dgtd.backends.compiled.step import register
from dgtd.backends.compiled.steps.gtd2 import centralised


class TDCParams(NamedTuple):
    eta: float
    alpha0: float
    timescale: float


@register("tdc", TDCParams, own=("w", "theta"), work=2)
@njit(cache=True, inline="always")
def tdc_step(p, own, sums, inbox, out, work, x, feat, b, i, agent, alpha, q):
    """w += alpha_k (1/N) sum_i ratio_i (delta_i phi_i - gamma phi'_i phi_i^T theta); theta as GTD2's."""
    centralised(True, p, own, sums, inbox, work, x, feat, b, alpha, q)
