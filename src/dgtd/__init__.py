"""dgtd: distributed policy evaluation with the primal-dual distributed GTD method and its baselines."""

import os as _os

# The compiled kernels synchronise their threads at every step when agents are spread over the cores; with
# OpenMP's default busy-waiting, a core shared with another process stalls every barrier (seen: 10x slower).
# Passive waiting costs little on an idle machine. A value the user set is kept.
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

__version__ = "0.1.0"
