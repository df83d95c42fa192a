"""``dgtd run --ranks R [--hosts FILE] ...``: start the run's R ranks with the mpi extra's mpiexec.

The same run as ``mpiexec -n R [-f FILE] dgtd run ...``, with two things mpiexec does not do: it finds the mpiexec
installed beside this Python (the ``mpi`` extra's MPICH, whatever else is on PATH), and it checks every machine of
the host file before any rank starts, so that a host that cannot be reached is one line and exit code 2 rather than
the launcher's error trace (``ssh: connect to host ... Connection refused`` and four lines of its process manager).
"""

from __future__ import annotations

import shutil
import signal
import socket
import subprocess
import sys
from pathlib import Path

from dgtd.errors import DgtdInputError
from dgtd.files import text_of

SSH_SECONDS = 10  # how long ssh may take to reach a host before it counts as unreachable
LOCAL = {"localhost", "127.0.0.1", "::1"}
INTERRUPTED_SECONDS = 60  # how long the ranks may take to end after Ctrl-C
ARGV: list[str] = []  # the command line `dgtd.cli.main` was given, which `launch` passes on to the ranks


def mpiexec() -> str:
    """The mpiexec beside this Python (the mpi extra's), else the first on PATH."""
    here = shutil.which("mpiexec", path=str(Path(sys.executable).parent))
    found = here or shutil.which("mpiexec")
    if found is None:
        raise DgtdInputError("--ranks starts the ranks with MPI's mpiexec, not installed here: pip install 'dgtd[mpi]'")
    return found


def read_hosts(path: str) -> list[str]:
    """The hosts of an MPICH host file (a line ``host`` or ``host:slots``; blank lines and # comments skipped)."""
    file = Path(path)
    if not file.is_file():
        raise DgtdInputError(f"--hosts {path}: no such file (a line host or host:slots per machine)")
    hosts = []
    for number, line in enumerate(text_of(file).splitlines(), 1):
        line = line.split("#")[0].strip()
        if not line:
            continue
        host, _, slots = line.partition(":")
        if not host or " " in host or (slots and not (slots.isdigit() and int(slots) > 0)):
            raise DgtdInputError(f"--hosts {path}, line {number}: {line!r} is not host or host:slots (slots >= 1)")
        hosts.append(host)
    if not hosts:
        raise DgtdInputError(f"--hosts {path} names no host (a line host or host:slots per machine)")
    return hosts


def check_reachable(hosts: list[str], path: str) -> None:
    """One line for the first host that does not resolve, or that ssh cannot reach without a password (the way
    mpiexec starts ranks on other machines) within ``SSH_SECONDS``."""
    me = {socket.gethostname(), socket.getfqdn()}
    for host in dict.fromkeys(hosts):
        if host in LOCAL or host in me:
            continue
        try:
            socket.getaddrinfo(host, 22)
        except OSError:
            raise DgtdInputError(f"host {host} of {path} cannot be reached: its name does not resolve") from None
        try:
            done = subprocess.run(
                ["ssh", "-o", "BatchMode=yes", "-o", f"ConnectTimeout={SSH_SECONDS}", host, "true"],
                capture_output=True,
                text=True,
                timeout=3 * SSH_SECONDS,
                stdin=subprocess.DEVNULL,
            )
            said = ([line for line in done.stderr.splitlines() if line.strip()] or ["no reason given"])[-1]
        except FileNotFoundError:
            raise DgtdInputError("mpiexec starts ranks on other machines over ssh, which is not installed") from None
        except subprocess.TimeoutExpired:
            done, said = None, f"no answer in {3 * SSH_SECONDS} s"
        if done is None or done.returncode != 0:
            raise DgtdInputError(
                f"host {host} of {path} cannot be reached ({said.strip()}); mpiexec starts the ranks over ssh: "
                f"check that `ssh {host} true` works without a password"
            )


def without(argv: list[str], names: tuple[str, ...]) -> list[str]:
    """``argv`` without the options ``names`` and their values (``--name V`` or ``--name=V``)."""
    out, skip = [], False
    for arg in argv:
        if skip:
            skip = False
        elif arg in names:
            skip = True
        elif not arg.startswith(tuple(f"{name}=" for name in names)):
            out.append(arg)
    return out


def launch(ranks: int | None, hosts: str | None, argv: list[str]) -> int:
    """Check the launch, start ``argv`` (a ``dgtd run`` command line) on ``ranks`` ranks, and return mpiexec's exit
    code (the ranks' own: 2 for bad input, as in one process)."""
    from dgtd.run import runtime

    if runtime.in_job():
        raise DgtdInputError("--ranks starts mpiexec itself: under mpiexec leave it out (mpiexec -n sets the ranks)")
    if ranks is None:
        raise DgtdInputError("--hosts names the machines of --ranks R: give --ranks too")
    if ranks < 1:
        raise DgtdInputError(f"--ranks must be at least 1, got {ranks}")
    listed = None if hosts is None else read_hosts(hosts)  # the host file's faults first, mpiexec installed or not
    command = [mpiexec(), "-n", str(ranks)]
    if hosts is not None and listed is not None:
        check_reachable(listed, hosts)
        command += ["-f", hosts]
    command += [sys.executable, "-m", "dgtd.cli", *without(argv, ("--ranks", "--hosts"))]
    # in a session of its own: a Ctrl-C, to the terminal's process group or to this process alone, reaches mpiexec
    # once, from here, and mpiexec passes it on to the ranks, which keep what they computed
    job = subprocess.Popen(command, start_new_session=True)
    try:
        return job.wait()
    except KeyboardInterrupt:
        job.send_signal(signal.SIGINT)
        try:
            return job.wait(timeout=INTERRUPTED_SECONDS) or 130  # as an interrupted run exits (MPICH's says 0)
        except subprocess.TimeoutExpired:
            return 130
        finally:
            job.kill()  # a second Ctrl-C, or ranks that did not end in time
            # said here too: a rank's own line can be lost when its job is aborted before mpiexec passes it on
            print("dgtd: interrupted; files already written are complete", file=sys.stderr, flush=True)
