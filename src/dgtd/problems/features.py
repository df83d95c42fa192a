"""Feature matrices Phi (S, q): row s is phi(s)."""

from __future__ import annotations

import numpy as np

from dgtd.errors import DgtdInputError


class FeatureMap:
    """A feature map of states: ``features(states (K, dim)) -> (K, q)``, with its width ``n_features`` = q."""

    def __init__(self, function, n_features: int):
        self.function, self.n_features = function, int(n_features)

    def __call__(self, states) -> np.ndarray:
        return self.function(states)


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


# Features for continuous states, each a callable features(states (K, dim)) -> (K, q) computed in one batch: what a
# simulator's source (`dgtd.sources.env.EnvSource`) calls once per block. ``low`` and ``high`` bound each state
# dimension; states outside are clipped to the box.


def _unit(states, low, high) -> np.ndarray:
    """States scaled to [0, 1]^dim by the box [low, high], clipped; shape (K, dim)."""
    x = np.atleast_2d(np.asarray(states, dtype=np.float64))
    low, high = (
        np.broadcast_to(np.asarray(low, np.float64), x.shape[1:]),
        np.broadcast_to(np.asarray(high, np.float64), x.shape[1:]),
    )
    if np.any(high <= low):
        raise DgtdInputError(f"the features' box needs high > low in every dimension, got low {low}, high {high}")
    return np.clip((x - low) / (high - low), 0.0, 1.0)


def fourier(order: int, low, high):
    """The Fourier cosine basis of Konidaris, Osentoski and Thomas (2011): phi_c(x) = cos(pi c . x) for every integer
    vector c in {0, ..., order}^dim, x scaled to [0, 1]^dim; (order + 1)^dim features, the first constant."""
    low = np.atleast_1d(np.asarray(low, np.float64))
    dim = low.size
    C = np.stack(np.meshgrid(*[np.arange(order + 1)] * dim, indexing="ij"), -1).reshape(-1, dim).astype(np.float64)

    def features(states):
        return np.cos(np.pi * _unit(states, low, high) @ C.T)

    return FeatureMap(features, len(C))


def rbf(centres_per_dim: int, low, high, width: float | None = None):
    """Gaussian radial basis functions on a regular grid of ``centres_per_dim``^dim centres over the box, with
    width (in the scaled units) one grid spacing unless given, plus a constant."""
    low = np.atleast_1d(np.asarray(low, np.float64))
    dim = low.size
    grid = np.linspace(0.0, 1.0, centres_per_dim)
    centres = np.stack(np.meshgrid(*[grid] * dim, indexing="ij"), -1).reshape(-1, dim)
    sigma = (1.0 / max(centres_per_dim - 1, 1)) if width is None else float(width)

    def features(states):
        x = _unit(states, low, high)
        sq = ((x[:, None, :] - centres[None, :, :]) ** 2).sum(-1)
        return np.concatenate([np.ones((len(x), 1)), np.exp(-sq / (2 * sigma**2))], axis=1)

    return FeatureMap(features, 1 + len(centres))


def tile_coding(tilings: int, tiles_per_dim: int, low, high):
    """Tile coding (Sutton and Barto 2018, section 9.5.4): ``tilings`` grids of ``tiles_per_dim``^dim tiles over the
    box, each offset by a fraction of a tile along every dimension (asymmetric offsets 1, 3, 5, ... as they
    recommend); phi is 1 on the one tile of each tiling that holds the state, so every state has ``tilings`` ones.
    tilings x (tiles_per_dim + 1)^dim features (one extra tile per dimension takes the offsets)."""
    low = np.atleast_1d(np.asarray(low, np.float64))
    dim = low.size
    n = tiles_per_dim + 1
    offsets = (np.arange(tilings)[:, None] * (2 * np.arange(dim) + 1)[None, :] / tilings) % 1.0  # (tilings, dim)
    strides = n ** np.arange(dim)

    def features(states):
        x = _unit(states, low, high) * tiles_per_dim  # in tile units
        idx = np.floor(x[:, None, :] + offsets[None, :, :]).astype(np.int64).clip(0, n - 1)  # (K, tilings, dim)
        cols = (idx * strides).sum(-1) + np.arange(tilings) * n**dim  # (K, tilings)
        out = np.zeros((len(x), tilings * n**dim))
        np.put_along_axis(out, cols, 1.0, axis=1)
        return out

    return FeatureMap(features, tilings * n**dim)


def one_hot(n_states: int):
    """Tabular features for a discrete state given as an index (K,) or (K, 1): row s of the identity."""
    eye = np.eye(n_states)

    def features(states):
        s = np.asarray(states).reshape(len(states), -1)[:, 0].astype(np.int64)
        if s.min(initial=0) < 0 or s.max(initial=0) >= n_states:
            raise DgtdInputError(f"a state index outside 0..{n_states - 1} reached the one-hot features")
        return eye[s]

    return FeatureMap(features, n_states)
