"""Algorithms by name: each entry is a frozen config class with ``name``, ``init`` and ``estimate``.

Configs, experiment files and sweeps look algorithms up here (never by a hard-coded list); the block
kernels that advance them are registered by the same name in each backend's ``BLOCKS``.
"""

from dgtd.algorithms.dgtd import DGTD

ALGORITHMS = {DGTD.name: DGTD}
