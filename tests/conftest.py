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


# A line at least every HEARTBEAT seconds while no test finishes (a first test compiles the kernels it runs, which on
# a slow or busy machine takes minutes): which tests are running, and for how long. It is written by the process that
# reports the tests (the one process, or pytest-xdist's controller, which hears every worker's tests start and end)
# to a copy of the terminal taken before any test's output is captured, so that no test's captured output holds it.
HEARTBEAT = 45.0


class _Heartbeat:
    def __init__(self, terminal: int):
        import threading
        import time

        self.terminal, self.clock = terminal, time.monotonic
        self.running: dict[str, float] = {}  # test -> when it started
        self.quiet_since = self.clock()
        self.lock, self.done = threading.Lock(), threading.Event()
        threading.Thread(target=self.beat, daemon=True).start()

    def started(self, nodeid: str) -> None:
        with self.lock:
            self.running[nodeid] = self.clock()

    def finished(self, nodeid: str) -> None:
        with self.lock:
            self.running.pop(nodeid, None)
            self.quiet_since = self.clock()

    def beat(self) -> None:
        while not self.done.wait(1.0):
            with self.lock:
                now = self.clock()
                if now - self.quiet_since < HEARTBEAT or not self.running:
                    continue
                self.quiet_since = now
                lines = [f"[{test} still running after {now - t:.0f} s: a first test compiles its kernels]"
                         for test, t in self.running.items()]  # fmt: skip
            os.write(self.terminal, ("\n" + "\n".join(lines) + "\n").encode())

    def stop(self) -> None:
        self.done.set()
        os.close(self.terminal)


_HEARTBEAT: list[_Heartbeat] = []


def pytest_sessionstart(session):
    if not hasattr(session.config, "workerinput"):  # not a pytest-xdist worker (its output goes nowhere)
        _HEARTBEAT.append(_Heartbeat(os.dup(1)))


def pytest_sessionfinish(session):
    while _HEARTBEAT:
        _HEARTBEAT.pop().stop()


def pytest_runtest_logstart(nodeid, location):
    for heart in _HEARTBEAT:
        heart.started(nodeid)


def pytest_runtest_logfinish(nodeid, location):
    for heart in _HEARTBEAT:
        heart.finished(nodeid)


@pytest.fixture
def few_rollouts(monkeypatch):
    """`dgtd compare` on a networked task with 10 rollouts an evaluation (its default 400 is the published measure,
    slow for a test)."""
    from dgtd.run import networked

    config_from = networked.config_from
    monkeypatch.setattr(networked, "config_from", lambda values: config_from({"rollouts": 10, **values}))
