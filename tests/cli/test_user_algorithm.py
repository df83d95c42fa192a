"""`dgtd run --algorithm path/to/file.py:Class`: a user's own algorithm, checked by `dgtd.check_algorithm` on the
NumPy reference first (its findings one line each), run on every backend, recorded so that its config.toml runs it
again from anywhere and a changed file is noticed."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers import one_line_error

FILE = Path(__file__).resolve().parents[1] / "envs" / "algorithms.py"
RUN = ("run", "paper-example-1", "-T", 1000, "--seeds", 2, "--no-plots", "--no-progress")


def metrics(out: Path) -> np.ndarray:
    rows = (out / "metrics.csv").read_text().splitlines()[1:]
    return np.array([float(r.rsplit(",", 1)[1] or "nan") for r in rows])


def test_a_users_algorithm_runs_and_its_config_names_its_file(run_cli, tmp_path):
    code, text, err = run_cli(
        *RUN, "--algorithm", f"{FILE}:RelaxedConsensusTD0", "--backend", "numpy", "--out", tmp_path / "a"
    )
    assert code == 0, err
    assert "relaxed-consensus-td0" in text
    assert f'name = "{FILE}:RelaxedConsensusTD0"' in (tmp_path / "a" / "config.toml").read_text()
    record = json.loads((tmp_path / "a" / "summary.json").read_text())["config"]
    assert len(record["algorithm_sha256"]) == 64  # a changed file is not resumed as if it were the same
    code, _, err = run_cli("run", tmp_path / "a" / "config.toml", "--out", tmp_path / "b")
    assert code == 0, err
    assert (tmp_path / "a" / "metrics.csv").read_bytes() == (tmp_path / "b" / "metrics.csv").read_bytes()


@pytest.mark.parametrize(
    "spec, words",
    [
        ("WrongFeature", ["dgtd.check_algorithm found", "case iid-noise on numpy", "TypeError"]),
        ("RaisingInit", ["its contract", "ValueError: the user's init failed"]),
        ("not_an_algorithm", ["not an algorithm class"]),
        ("NoSuchClass", ["has no NoSuchClass"]),
    ],
)
def test_a_users_faulty_algorithm_is_one_line(run_cli, tmp_path, spec, words):
    one_line_error(*run_cli(*RUN, "--algorithm", f"{FILE}:{spec}", "--out", tmp_path / "o"), *words)
    assert not (tmp_path / "o" / "summary.json").exists()


def test_an_unknown_algorithm_name_says_a_file_may_be_given(run_cli, tmp_path):
    one_line_error(*run_cli(*RUN, "--algorithm", "tdx", "--out", tmp_path / "o"), "unknown algorithm", "file.py:Class")


@pytest.mark.slow
def test_a_users_algorithm_gives_the_references_numbers_on_every_backend(run_cli, tmp_path):
    """Compiled from its one definition (numba) and traced (JAX, where installed): the NumPy reference's metrics to
    1e-12 (measured 2e-15 for both)."""
    backends = ["numpy", "numba"]
    try:
        import jax  # noqa: F401

        backends.append("jax")
    except ImportError:
        pass
    for backend in backends:
        code, _, err = run_cli(
            *RUN, "--algorithm", f"{FILE}:RelaxedConsensusTD0", "--backend", backend, "--out", tmp_path / backend
        )
        assert code == 0, err
    ref = metrics(tmp_path / "numpy")
    for backend in backends[1:]:
        got = metrics(tmp_path / backend)
        assert np.array_equal(np.isnan(ref), np.isnan(got))
        assert np.nanmax(np.abs(got - ref) / np.maximum(1.0, np.abs(ref))) < 1e-12, backend
