"""What comparisons need of the algorithms of `dgtd.algorithms.ALGORITHMS`: descriptions, construction by name,
and the number of parameter vectors each sends per link."""

from __future__ import annotations

import dataclasses

from dgtd.algorithms import ALGORITHMS
from dgtd.errors import DgtdInputError

DESCRIPTIONS = {
    "dgtd": "the paper's primal-dual distributed GTD (Algorithm 1)",
    "gtd2": "centralised GTD2 on the average reward (Sutton et al. 2009)",
    "tdc": "centralised TDC on the average reward (Sutton et al. 2009)",
    "td0": "centralised TD(0) on the average reward",
    "consensus-td0": "distributed TD(0) with Metropolis consensus (Doan, Maguluri, Romberg 2019)",
    "pd-td": "Laplacian primal-dual distributed TD (Lim and Lee 2025)",
    "local": "each agent runs GTD2 on its own reward, no communication",
}


def make_algorithm(name: str, **fields):
    """The config of algorithm ``name`` with ``fields`` overriding its defaults."""
    if name not in ALGORITHMS:
        raise DgtdInputError(f"unknown algorithm {name!r} (known: {', '.join(ALGORITHMS)})")
    cls = ALGORITHMS[name]
    known = {f.name for f in dataclasses.fields(cls)}
    bad = sorted(set(fields) - known)
    if bad:
        raise DgtdInputError(f"algorithm {name} has no setting {', '.join(bad)} (it has: {', '.join(sorted(known))})")
    return cls(**fields)


def messages_per_edge(algorithm) -> int:
    """Parameter vectors an up edge carries per step, both directions together."""
    return 2 * int(getattr(algorithm, "vectors_per_direction", 0))
