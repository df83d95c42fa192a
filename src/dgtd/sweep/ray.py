"""A `concurrent.futures.Executor` on Ray, so that a sweep runs the same jobs on a laptop pool or a cluster.

Ray is optional (``pip install "dgtd[ray]"``) and imported only here. Without ``address`` a throw-away local
Ray is started on 127.0.0.1, without dashboard or usage reporting, and stopped by `shutdown`; Ray 2.59 and later
(the version the extra asks for) turn token authentication on for such a local cluster by default. Ray's processes still listen on every interface of the machine (measured with Ray 2.60 in a
network namespace with a second interface; tests/test_ray_network.py): the token, which Ray generates for the
local cluster and which only the user's account can read, is what keeps others on the network from submitting
work; with
``address`` the executor connects to a running cluster and `shutdown` only disconnects. A task whose
worker process dies is retried by Ray (``max_retries``).
"""

from __future__ import annotations

import logging
import os
from concurrent.futures import Executor, Future

from dgtd.errors import DgtdInputError


def import_ray():
    try:
        import ray
    except ImportError:
        raise DgtdInputError("--executor ray needs Ray, which is not installed: pip install 'dgtd[ray]'") from None
    return ray


class RayExecutor(Executor):
    """Runs ``fn(*args)`` as a Ray task of ``num_cpus_per_task`` CPUs; futures are Ray's own."""

    def __init__(self, address: str | None = None, num_cpus: int | None = None, num_cpus_per_task: float = 1,
                 max_retries: int = 3):
        self.ray = import_ray()
        self.options = {"num_cpus": num_cpus_per_task, "max_retries": max_retries}
        self._remote: dict = {}
        self._refs: list = []
        if address is not None:
            self.ray.init(address=address, logging_level=logging.WARNING, log_to_driver=False)
        else:
            os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
            self.ray.init(num_cpus=num_cpus, include_dashboard=False, _node_ip_address="127.0.0.1",
                          logging_level=logging.WARNING, log_to_driver=False)

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
