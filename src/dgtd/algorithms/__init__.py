"""Algorithms by name: each entry is a frozen config class with ``name``, ``init`` and ``estimate``.

Configs, experiment files and sweeps look algorithms up here (never by a hard-coded list); the block
kernels that advance them are registered by the same name in each backend's ``BLOCKS``. Besides DGTD
(the paper's Algorithm 1) they are the baselines it is compared with (`dgtd.algorithms.registry`).
"""

from dgtd.algorithms.consensus_td0 import ConsensusTD0
from dgtd.algorithms.dgtd import DGTD
from dgtd.algorithms.gtd2 import GTD2
from dgtd.algorithms.local import Local
from dgtd.algorithms.pd_td import PDTD
from dgtd.algorithms.td0 import TD0
from dgtd.algorithms.tdc import TDC

ALGORITHMS = {cls.name: cls for cls in (DGTD, GTD2, TDC, TD0, ConsensusTD0, PDTD, Local)}
