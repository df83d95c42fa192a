"""Problem files: an .npz holding P (S, S), R (N, S), Phi (S, q) and scalar gamma (optional scalar sigma)."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from dgtd.errors import DgtdInputError
from dgtd.files import read_npz
from dgtd.problems.model import Problem, make_problem

REQUIRED = ("P", "R", "Phi", "gamma")


def load_problem(path: str, reward_noise: str = "none") -> Problem:
    """Load and validate a problem file; every failure is a one-line `DgtdInputError`."""
    p = Path(path)
    arrays = read_npz(p, "problem file", "give an .npz saved with numpy.savez that holds arrays P (S, S), R (N, S), "
                      "Phi (S, q) and a scalar gamma", required=REQUIRED)
    for k in ("gamma", "sigma"):
        if k in arrays and np.asarray(arrays[k]).size != 1:
            raise DgtdInputError(f"{k} in {path} must be a scalar, got shape {np.asarray(arrays[k]).shape}")
    sigma = float(arrays["sigma"]) if "sigma" in arrays else None
    try:
        gamma = float(np.asarray(arrays["gamma"]).reshape(()))
    except (TypeError, ValueError):
        raise DgtdInputError(f"gamma in {path} must be a number") from None
    return make_problem(arrays["P"], arrays["R"], arrays["Phi"], gamma, sigma=sigma, reward_noise=reward_noise, name=p.stem)


def save_problem(path: str, problem: Problem) -> None:
    """Write a problem's Markov reward process form (P, R, Phi, gamma, sigma) as .npz."""
    np.savez(path, P=problem.P, R=problem.R, Phi=problem.Phi, gamma=problem.gamma, sigma=problem.sigma)


def file_digest(path: str) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()
