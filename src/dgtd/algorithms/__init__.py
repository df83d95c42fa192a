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


def growing_mode(algorithm, moments, network) -> str:
    """A one-line warning where no step makes every mode of ``algorithm``'s mean dynamics contract on the problem
    (``moments``: a model's or an estimated reference's) and its network, at any step size: a mode grows, so a run
    diverges there. It names the registered methods, on their defaults, whose mean dynamics do contract there
    (`dgtd.algorithms.mean_dynamics.first_step`). "" where a step contracts, or the dynamics are too large to
    analyse."""
    from dgtd.algorithms.mean_dynamics import first_step

    alpha_1, why = first_step(algorithm, moments, network)
    if alpha_1 is not None or not why.startswith("no step"):
        return ""
    fine = [name for name, cls in ALGORITHMS.items() if first_step(cls(), moments, network)[0] is not None]
    return (
        f"warning: no step makes every mode of {algorithm.name}'s mean dynamics contract on this problem (a mode "
        f"grows at every step size: expect it to diverge); the methods whose mean dynamics contract here: "
        f"{', '.join(fine) or 'none'}; the steps given are kept"
    )


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
    "growing_mode",
    "make_algorithm",
]
