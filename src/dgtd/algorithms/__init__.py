"""The algorithms, each a frozen dataclass of hyperparameters with pure ``init`` / ``sends`` / ``update`` /
``estimate`` from its arithmetic written once, and the hooks of `dgtd.algorithms.base`, registered by name in
`ALGORITHMS`.

Configs, experiment files, sweeps, comparisons and kernels look algorithms up here by name, never by a list of their
own. Besides DGTD (the paper's Algorithm 1) they are the baselines it is compared with. Adding an algorithm is one
file with its class, and a line below.
"""

from __future__ import annotations

import dataclasses

from dgtd.algorithms.consensus_td0 import ConsensusTD0
from dgtd.algorithms.consensus_tdrc import ConsensusTDRC
from dgtd.algorithms.dgtd import DGTD
from dgtd.algorithms.gtd2 import GTD2
from dgtd.algorithms.local import Local
from dgtd.algorithms.pd_td import PDTD
from dgtd.algorithms.td0 import TD0
from dgtd.algorithms.td_tracking import TDTracking
from dgtd.algorithms.tdc import TDC
from dgtd.algorithms.tdc_tracking import TDCTracking
from dgtd.algorithms.tdrc import TDRC
from dgtd.errors import DgtdInputError

ALGORITHMS = {
    cls.name: cls
    for cls in (
        *(DGTD, GTD2, TDC, TDRC, TD0, ConsensusTD0, PDTD),
        *(TDTracking, TDCTracking, ConsensusTDRC, Local),
    )
}


def make_algorithm(name: str, **fields):
    """The algorithm ``name`` with ``fields`` overriding its defaults.

    >>> make_algorithm("gtd2", alpha0=0.5).eta
    1.0
    """
    if name not in ALGORITHMS:
        raise DgtdInputError(f"unknown algorithm {name!r} (known: {', '.join(ALGORITHMS)})")
    cls = ALGORITHMS[name]
    known = {f.name for f in dataclasses.fields(cls)}
    bad = sorted(set(fields) - known)
    if bad:
        raise DgtdInputError(f"algorithm {name} has no setting {', '.join(bad)} (it has: {', '.join(sorted(known))})")
    return cls(**fields)


__all__ = [
    "ALGORITHMS",
    "ConsensusTD0",
    "ConsensusTDRC",
    "DGTD",
    "GTD2",
    "Local",
    "PDTD",
    "TD0",
    "TDC",
    "TDCTracking",
    "TDRC",
    "TDTracking",
    "make_algorithm",
]
