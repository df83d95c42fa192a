"""A results directory has one owner: a lock held while a command writes into it, and one kind of results in it.

Two commands started into the same directory would each write their files, and the directory would hold the config
of one beside the results of the other. The writer holds an exclusive lock on ``DIR/.dgtd.lock`` (``flock``: the
system drops it when the process ends, however it ends) and writes into it who holds it, which a second writer's
refusal names. A run, a comparison and a sweep leave different files; one is not written into another's directory
unless the user says ``--overwrite``.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

from dgtd.errors import DgtdInputError

LOCK = ".dgtd.lock"
KINDS = ("run", "comparison", "sweep", "learning run")


def kind_of(out: Path) -> str | None:
    """Which command's results ``out`` holds, from the files only that command writes; None when it holds none."""
    out = Path(out)
    if (out / "jobs").is_dir() or (out / "sweep.json").exists():
        return "sweep"
    if (out / "agent_errors.npz").exists() or (out / "parts").is_dir():
        return "comparison"
    header = _first_line(out / "config.toml")  # (a networked run's and comparison's say so: `dgtd.cli.networked`)
    if header.startswith("# dgtd networked comparison"):
        return "comparison"
    if header.startswith("# dgtd networked") or header.startswith("# dgtd learn"):
        return "learning run"
    if (out / "policies.npz").exists() or (out / "learning-checkpoint.npz").exists():
        return "learning run"
    if any((out / name).exists() for name in ("trajectory.npz", "checkpoint.npz", "summary.json", "config.toml")):
        return "run"
    return None


def _first_line(path: Path) -> str:
    """The first line of a text file ('' where there is none or it cannot be read)."""
    try:
        with open(path, encoding="utf-8", errors="replace") as f:
            return f.readline()
    except OSError:
        return ""


class Owner:
    """The lock on a results directory for one ``kind`` of writer; `release` (or the process's end) lets it go."""

    def __init__(self, out: Path, kind: str, overwrite: bool = False):
        self.out, self.kind, self.fd = Path(out), kind, None
        there = kind_of(self.out)
        if there is not None and there != kind and not overwrite:
            raise DgtdInputError(
                f"{self.out} holds the results of a {there}, not of a {kind}; choose another --out, "
                f"or pass --overwrite to write a {kind} there"
            )
        try:
            self.out.mkdir(parents=True, exist_ok=True)
            import fcntl
        except ImportError:  # no flock (Windows): the directory is not locked
            return
        except OSError as e:
            raise DgtdInputError(
                f"the results folder {self.out} cannot be made ({e.strerror or e}); choose another --out, in a folder "
                "you can write to"
            ) from None
        try:
            fd = os.open(self.out / LOCK, os.O_RDWR | os.O_CREAT, 0o666)
        except OSError as e:
            raise DgtdInputError(
                f"the results folder {self.out} cannot be written ({e.strerror or e}); choose another --out, in a "
                "folder you can write to"
            ) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = os.read(fd, 4096).decode(errors="replace").strip() or "another process"
            os.close(fd)
            raise DgtdInputError(
                f"{self.out} is being written by {holder}; wait for it to end, or choose another --out"
            ) from None
        os.ftruncate(fd, 0)
        os.write(
            fd,
            f"a dgtd {kind} (process {os.getpid()}, `{' '.join(['dgtd', *sys.argv[1:]])[:200]}`, since "
            f"{time.strftime('%Y-%m-%d %H:%M:%S')})\n".encode(),
        )
        self.fd = fd

    def release(self) -> None:
        if self.fd is not None:
            os.ftruncate(self.fd, 0)
            os.close(self.fd)  # closing the last descriptor drops the flock
            self.fd = None

    def __enter__(self) -> Owner:
        return self

    def __exit__(self, *exc) -> None:
        self.release()
