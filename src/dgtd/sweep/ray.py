"""A `concurrent.futures.Executor` on Ray, so that a sweep runs the same jobs on a laptop pool or a cluster.

Ray is optional (``pip install "dgtd[ray]"``) and imported only here. Without ``address`` a throw-away local
Ray is started on 127.0.0.1, without dashboard or usage reporting, and stopped by `shutdown`; Ray 2.59 and later
(the version the extra asks for) turn token authentication on for such a local cluster by default. Ray's
processes still listen on every interface of the machine (measured with Ray 2.60 in a
network namespace with a second interface; tests/sweep/test_ray_network.py): the token, which Ray generates for the
local cluster and which only the user's account can read, is what keeps others on the network from submitting
work; with
``address`` the executor connects to a running cluster and `shutdown` only disconnects. A task whose
worker process dies is retried by Ray (``max_retries``).
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import sys
import tempfile
from concurrent.futures import Executor, Future

from dgtd.errors import DgtdInputError


def import_ray():
    try:
        import ray
    except ImportError:
        raise DgtdInputError("--executor ray needs Ray, which is not installed: pip install 'dgtd[ray]'") from None
    return ray


@contextlib.contextmanager
def _stderr_dropped():
    """File descriptor 2 on /dev/null for a while (what Ray's C++ core writes there, too, is dropped)."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def connection_refused(address: str, error: Exception) -> str:
    """The one line for a cluster that refused the connection: clusters of Ray 2.60 on ask for a token, which a client
    connecting by address sends only with RAY_AUTH_MODE=token."""
    if os.environ.get("RAY_AUTH_MODE", "").lower() != "token":
        return (
            f"cannot connect to the Ray cluster at {address} ({error}): a cluster of Ray 2.60 or later asks for "
            "its token, which is sent only with RAY_AUTH_MODE=token set (the token is read from RAY_AUTH_TOKEN, "
            "RAY_AUTH_TOKEN_PATH or ~/.ray/auth_token); set it and run again (docs/experiments.md: Pointing the "
            "same command at a Ray cluster)"
        )
    return (
        f"cannot connect to the Ray cluster at {address} ({error}): check that it runs (`ray status --address "
        f"{address}`) and that the token dgtd sends (RAY_AUTH_TOKEN, RAY_AUTH_TOKEN_PATH or ~/.ray/auth_token) is "
        "the cluster's (docs/experiments.md: Pointing the same command at a Ray cluster)"
    )


class RayExecutor(Executor):
    """Runs ``fn(*args)`` as a Ray task of ``num_cpus_per_task`` CPUs; futures are Ray's own."""

    def __init__(
        self,
        address: str | None = None,
        num_cpus: int | None = None,
        num_cpus_per_task: float = 1,
        max_retries: int = 3,
    ):
        self.ray = import_ray()
        self.options = {"num_cpus": num_cpus_per_task, "max_retries": max_retries}
        self._remote: dict = {}
        self._refs: list = []
        self._session: str | None = None  # a local Ray's folder, removed at shutdown
        if address is not None:
            try:
                with _stderr_dropped():  # Ray's core logs a line per attempt while a cluster refuses it
                    self.ray.init(address=address, logging_level=logging.WARNING, log_to_driver=False)
            except ConnectionError as e:
                raise DgtdInputError(connection_refused(address, e)) from None
        else:
            os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
            # "local": a new instance of our own, even where a `ray start` cluster runs on this machine (without it,
            # init() joins the latest one, or hangs on one that stopped uncleanly)
            self._session = _session_folder()
            self.ray.init(
                address="local",
                num_cpus=num_cpus,
                include_dashboard=False,
                _node_ip_address="127.0.0.1",
                _temp_dir=self._session,
                logging_level=logging.WARNING,
                log_to_driver=False,
            )

    def submit(self, fn, /, *args, **kwargs) -> Future:
        if fn not in self._remote:
            self._remote[fn] = self.ray.remote(fn).options(**self.options)
        ref = self._remote[fn].remote(*args, **kwargs)
        self._refs.append(ref)
        return ref.future()

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        if self.ray.is_initialized():
            if cancel_futures and self._refs:
                _, running = self.ray.wait(self._refs, num_returns=len(self._refs), timeout=0)
                for ref in running:
                    self.ray.cancel(ref, force=True)
            self.ray.shutdown()
        if self._session is not None:
            shutil.rmtree(self._session, ignore_errors=True)
            self._session = None


SOCKET_PATH_MAX = 107  # bytes of a Unix socket's path; Ray's deepest is <folder>/session_<date>_<pid>/sockets/...


def _session_folder() -> str:
    """A folder of our own for a local Ray's session (Ray leaves $TMPDIR/ray/session_* behind otherwise), where its
    sockets' paths fit: under the temporary folder, or /tmp where that folder's path is too long."""
    root = tempfile.gettempdir()
    if len(root) + 80 > SOCKET_PATH_MAX and os.path.isdir("/tmp"):
        root = "/tmp"
    return tempfile.mkdtemp(prefix="dgtd-ray-", dir=root)
