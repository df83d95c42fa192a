"""This process's place in a job, as the command line needs it: whether it writes the results and speaks, how a
results folder is claimed once for every process, what may not run spread, the watchdog, and how a job is stopped.
One process outside mpiexec is a job of one; the ranks of an mpiexec job are the MPI runtime's
(`dgtd.backends.mpi`), which this module alone names above the run's layout (`dgtd.run.layout`)."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

from dgtd.backends import mpi
from dgtd.errors import DgtdInputError
from dgtd.run.checkpoint import save_checkpoint

T = TypeVar("T")
SPREAD = ("run", "learn", "networked")  # the commands whose agents spread over the ranks of an mpiexec job


def in_job() -> bool:
    """Whether this process is a rank of an mpiexec job (of any size, 1 included)."""
    return mpi.launched()


def writes() -> bool:
    """Whether this process writes the results and reports them: the only one, or rank 0 of a job."""
    return mpi.rank() == 0


def ranks() -> int:
    """How many processes the job has (1 outside mpiexec): a learning run's agents spread over them where more."""
    return mpi.size()


def speaks() -> bool:
    """Whether this process prints: the job says each thing once, from the process that writes."""
    return not in_job() or writes()


def check_command(command: str | None) -> None:
    """Under mpiexec with more than one rank, `dgtd run`, `dgtd learn` and `dgtd networked` spread their agents over
    the ranks; any other command would run once on every rank and write the same files from each: one line."""
    if in_job() and mpi.spread() and command not in (None, *SPREAD):
        raise DgtdInputError(
            "under mpiexec only `dgtd run`, `dgtd learn` and `dgtd networked` spread their agents over the ranks; run "
            f"`dgtd {command}` in one process"
        )


def check_supported(algorithm, channel, n_agents: int, backend: str, asynchronous: bool) -> None:
    """One line for what the ranks do not run (yet), the same on every process, before anything starts."""
    mpi.check_supported(algorithm, channel, n_agents, backend, asynchronous)


def claimed(claim: Callable[[], T], follow: Callable[[], T]) -> T:
    """``claim()`` on the process that writes (it claims the results folder, checks a resume, writes config.toml),
    its refusal, if any, said on every process; the others then ``follow()`` (read what they resume from)."""
    if not writes():
        said = mpi.world().bcast(None, root=0)
        if said is not None:
            raise DgtdInputError(said)
        return follow()
    try:
        result = claim()
    except DgtdInputError as e:
        if in_job():
            mpi.world().bcast(str(e), root=0)
        raise
    if in_job():
        mpi.world().bcast(None, root=0)
    return result


def checkpoint_saver(algorithm, path: Path, record: dict) -> Callable | None:
    """The checkpoint writer of a run into ``path`` (`dgtd.run.checkpoint.save_checkpoint`): the process that writes,
    or where the agents are spread every rank, each its shard; None on a process that saves nothing."""
    comm = mpi.world() if mpi.spreads(algorithm) else None
    if not (writes() or comm is not None):
        return None
    return lambda snapshot: save_checkpoint(path, snapshot, record, comm)


def save_learners(path: Path, snapshot: dict, record: dict) -> None:
    """A learning run's checkpoint (`dgtd.run.checkpoint.save_checkpoint`): in a job of ranks, every rank its shard
    (a collective), its agents being spread whenever there are ranks (`dgtd.run.layout.learner_layout`)."""
    save_checkpoint(path, snapshot, record, mpi.world() if mpi.spread() else None)


def watch(algorithm, every: int) -> None:
    """Where the agents are spread, a rank that waits too long for the others ends with one line
    (`dgtd.backends.mpi.Watchdog`, DGTD_MPI_TIMEOUT seconds)."""
    if mpi.spreads(algorithm):
        again = "run the same command again to continue from it" if every else "rerun"
        mpi.WATCHDOG.start(float(os.environ.get("DGTD_MPI_TIMEOUT", mpi.TIMEOUT)), again)


def stop_job(code: int, line: str) -> None:
    """Stop the other processes of the job too, rather than let them wait for this one (nothing outside a job)."""
    mpi.abort(code, line)
