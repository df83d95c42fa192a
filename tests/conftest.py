"""Shared helpers: running the CLI in this process or as a subprocess of this checkout's code."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from dgtd.problems.generators import random_mdp_problem, random_problem

SRC = Path(__file__).resolve().parents[1] / "src"


def cli_env(**extra) -> dict:
    """Environment for a `python -m dgtd.cli` subprocess that imports this checkout's dgtd."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(SRC), *filter(None, [env.get("PYTHONPATH")])])
    env.update(extra)
    return env


def dgtd_cmd(*args) -> list[str]:
    return [sys.executable, "-m", "dgtd.cli", *map(str, args)]


@pytest.fixture
def run_cli(capsys):
    """Run `dgtd ARGS` in-process; returns (exit code, stdout, stderr)."""
    from dgtd.cli import main

    def call(*args):
        try:
            main([str(a) for a in args])
            code = 0
        except SystemExit as e:
            code = e.code or 0
        out = capsys.readouterr()
        return code, out.out, out.err

    return call


def run_subprocess(*args, **kw) -> subprocess.CompletedProcess:
    return subprocess.run(dgtd_cmd(*args), env=cli_env(), capture_output=True, text=True, **kw)


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture
def small_problem(rng):
    return random_problem(6, 4, 3, rng, gamma=0.85)


@pytest.fixture
def off_policy_problem(rng):
    return random_mdp_problem(5, (2, 3), 3, rng, gamma=0.8, off_policy=True)


# A line at least every HEARTBEAT seconds while one test runs long (a first test compiles the kernels it runs, which
# on a slow or busy machine takes minutes in which no test finishes): written to a copy of the terminal taken before
# any test's output is captured, so that no test's captured output holds it.
HEARTBEAT = 45.0
_TERMINAL: list[int] = []


def pytest_sessionstart(session):
    _TERMINAL.append(os.dup(1))


def pytest_sessionfinish(session):
    while _TERMINAL:
        os.close(_TERMINAL.pop())


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    import threading
    import time

    done = threading.Event()

    def beat():
        start = time.monotonic()
        while not done.wait(HEARTBEAT) and _TERMINAL:
            seconds = time.monotonic() - start
            line = f"\n[{item.nodeid} still running after {seconds:.0f} s: a first test compiles its kernels]\n"
            os.write(_TERMINAL[0], line.encode())

    if _TERMINAL:
        threading.Thread(target=beat, daemon=True).start()
    try:
        yield
    finally:
        done.set()
