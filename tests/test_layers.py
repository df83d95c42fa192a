"""The layers go one way: the import-linter contracts of pyproject.toml hold for the package as it is."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_import_linter_contracts_hold(monkeypatch):
    from importlinter.cli import lint_imports

    monkeypatch.chdir(ROOT)
    assert lint_imports(config_filename=str(ROOT / "pyproject.toml"), no_cache=True) == 0


def test_the_contract_catches_an_upward_import(tmp_path, monkeypatch):
    """A copy of the package in which a graph module imports the run loop breaks the layers contract."""
    import shutil
    import sys

    from importlinter.cli import lint_imports

    src = tmp_path / "src"
    shutil.copytree(ROOT / "src" / "dgtd", src / "dgtd", ignore=shutil.ignore_patterns("__pycache__"))
    target = src / "dgtd" / "graphs" / "topologies.py"
    target.write_text(target.read_text() + "\nfrom dgtd.run import loop  # noqa: E402,F401\n")
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(src))
    for name in [m for m in sys.modules if m == "dgtd" or m.startswith("dgtd.")]:
        monkeypatch.delitem(sys.modules, name)
    assert lint_imports(config_filename=str(tmp_path / "pyproject.toml"), no_cache=True) == 1


@pytest.mark.parametrize("module", ["dgtd.samples", "dgtd.algorithms", "dgtd.backends.reference"])
def test_the_lower_layers_import_without_the_compiled_backend(module):
    """The bottom of the stack and the reference backend need neither numba nor matplotlib."""
    import subprocess
    import sys

    code = f"import sys, {module}; print(sorted({{'numba', 'matplotlib'}} & set(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
