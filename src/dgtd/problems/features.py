"""Feature matrices Phi (S, q): row s is phi(s)."""

from __future__ import annotations

import numpy as np


def tabular(n_states: int) -> np.ndarray:
    """Phi = I: the tabular case of the paper's remark after Proposition 1."""
    return np.eye(n_states)


def gaussian_rbf(states, centers, width: float = 1.0) -> np.ndarray:
    """phi_j(s) = exp(-(s - c_j)^2 / width^2).

    The paper's Example 1 is ``gaussian_rbf([1, 2, 3, 4], [0, 4])``: phi(s) = [exp(-s^2), exp(-(s-4)^2)].
    States and centres may be vectors (rows of a (S, dim) array) for a multi-dimensional state space.
    """
    s = np.asarray(states, dtype=np.float64)
    c = np.asarray(centers, dtype=np.float64)
    if s.ndim == 1:
        s = s[:, None]
    if c.ndim == 1:
        c = c[:, None]
    sq = ((s[:, None, :] - c[None, :, :]) ** 2).sum(-1)
    return np.exp(-sq / width**2)


def from_matrix(Phi) -> np.ndarray:
    """A user-given feature matrix, as float64 (checked for rank by `make_problem`)."""
    return np.asarray(Phi, dtype=np.float64)
