"""dgtd: distributed policy evaluation with the primal-dual distributed GTD method and its baselines."""

import os as _os

# When agents are spread over the cores, the compiled kernels synchronise their threads at every step. Threads
# that go to sleep at once pay two wake-ups per step (measured on a 2-core virtual machine: about 0.1 ms per step,
# half the run time with a few hundred agents); OpenMP's default spin of a few milliseconds stalls every step on a
# core shared with another busy process (seen: 10x slower). A short spin keeps the fast hand-over between steps
# and bounds what a shared core loses (there: about 25 % slower than not spinning). Values the user set are kept.
if "OMP_WAIT_POLICY" not in _os.environ and "GOMP_SPINCOUNT" not in _os.environ:
    _os.environ["GOMP_SPINCOUNT"] = "10000"

__version__ = "0.1.0"
