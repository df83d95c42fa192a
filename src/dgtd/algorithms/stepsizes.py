"""Step-size sequences alpha_k, k = 0, 1, ... (paper remarks after Proposition 7)."""

from __future__ import annotations

import numpy as np

from dgtd.errors import DgtdInputError

SCHEDULES = ("sqrt", "harmonic", "constant")


def check_schedule(schedule: str, alpha0: float, beta: float) -> None:
    if schedule not in SCHEDULES:
        raise DgtdInputError(f"step-size schedule must be one of {', '.join(SCHEDULES)}, got {schedule!r}")
    if not (np.isfinite(alpha0) and alpha0 > 0):
        raise DgtdInputError(f"alpha0 must be a positive number, got {alpha0}")
    if schedule != "constant" and not (np.isfinite(beta) and beta > 0):
        raise DgtdInputError(f"beta must be a positive number, got {beta}")


def step_sizes(schedule: str, alpha0: float, beta: float, k0: int, k1: int) -> np.ndarray:
    """alpha_k for k in [k0, k1): alpha0 / sqrt(k + beta) (default, the paper's), alpha0 / (k + beta), or alpha0."""
    k = np.arange(k0, k1, dtype=np.float64)
    if schedule == "sqrt":
        return alpha0 / np.sqrt(k + beta)
    if schedule == "harmonic":
        return alpha0 / (k + beta)
    return np.full(k.shape, float(alpha0))


def describe(schedule: str, alpha0: float, beta: float) -> str:
    """alpha_k in words: "10/sqrt(k+1000)", "1/(k+10)" or "0.1 (constant)"."""
    if schedule == "constant":
        return f"{alpha0:.4g} (constant)"
    return f"{alpha0:.4g}/{'sqrt(k+' if schedule == 'sqrt' else '(k+'}{beta:g})"
