"""Features for continuous states (batched): Fourier basis, RBF, tile coding, one-hot, against hand-computed values."""

from __future__ import annotations

import numpy as np
import pytest

from dgtd.errors import DgtdInputError
from dgtd.problems.features import fourier, one_hot, rbf, tile_coding


def test_fourier_basis_is_cos_pi_c_dot_x():
    """Order 1 in two dimensions: c in {(0,0), (0,1), (1,0), (1,1)}; x = (0.25, 0.5) after scaling [0, 2]^2."""
    f = fourier(1, [0.0, 0.0], [2.0, 2.0])
    phi = f(np.array([[0.5, 1.0]]))
    x = np.array([0.25, 0.5])
    want = [np.cos(np.pi * np.dot(c, x)) for c in ((0, 0), (0, 1), (1, 0), (1, 1))]
    assert f.n_features == 4 and np.allclose(phi, [want])


def test_rbf_peaks_at_its_centres():
    f = rbf(3, [0.0], [1.0])  # centres 0, 0.5, 1, width 0.5
    phi = f(np.array([[0.5], [1.0]]))
    assert f.n_features == 4 and np.allclose(phi[:, 0], 1.0)
    assert np.isclose(phi[0, 2], 1.0) and np.isclose(phi[0, 1], np.exp(-0.25 / 0.5))


def test_tile_coding_lights_one_tile_per_tiling():
    f = tile_coding(4, 8, [-1.0, 0.0], [1.0, 10.0])
    states = np.random.default_rng(0).uniform([-1.0, 0.0], [1.0, 10.0], (200, 2))
    phi = f(states)
    assert phi.shape == (200, f.n_features) and np.all(phi.sum(1) == 4)
    near, far = f(np.array([[0.0, 5.0], [0.01, 5.0], [0.9, 1.0]]))[[0, 1]], f(np.array([[0.9, 1.0]]))[0]
    assert (near[0] * near[1]).sum() >= 3  # a close state shares most of its tiles
    assert (near[0] * far).sum() == 0  # a far one none


def test_one_hot_and_its_bad_index():
    f = one_hot(3)
    assert np.array_equal(f(np.array([[2], [0]])), [[0, 0, 1], [1, 0, 0]])
    with pytest.raises(DgtdInputError, match="outside"):
        f(np.array([[3]]))


def test_a_box_without_volume_is_refused():
    with pytest.raises(DgtdInputError, match="high > low"):
        fourier(1, [0.0], [0.0])(np.zeros((1, 1)))
