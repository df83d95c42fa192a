"""What a channel is: the protocol every link model follows, registered by name in `dgtd.channels.CHANNELS`.

A channel is a frozen dataclass of its link parameters with pure ``init`` / ``deliver`` over a state of its own (a
NamedTuple, as an algorithm's): the counts ``messages`` and ``bits`` (B,) that every state holds, and whatever else
the link model carries from step to step, each field either per seed (B,) or per seed and arc (B, arcs, ...). The
run loop, the checkpoints and the MPI runtime read nothing else of a state: they save its fields by name, and cut
and join its per-arc fields (`per_arc_fields`) where the arcs are spread over ranks.

Beside its NumPy definition a link model has:

- its MPI part, ``share``: the channel over a rank's arcs and agents (each one's own parameters, as the whole
  network's run has them), which draws the numbers the whole network draws for them (`dgtd.streams`);
- its compiled part, a twin in `dgtd.backends.compiled` registered under its name there
  (`dgtd.backends.compiled.TWINS`), tested equal; the compiled backend hands a channel without one to the NumPy
  reference with a one-line notice (JAX runs any whose receivers hold no copies);
- its mean mixing, ``mean_mixing``: E of the Laplacian an algorithm mixes with over what it hears, whose left null
  vector weighs the agents' rewards at the fixed point (`dgtd.problems.exact.weighted_w_star`).
"""

from __future__ import annotations

from typing import ClassVar, Protocol, runtime_checkable

import numpy as np

from dgtd.channels.arcs import Arcs

BITS_PER_NUMBER = 64  # a message's coordinates are float64


@runtime_checkable
class Channel(Protocol):
    """The link model between the agents: what each agent hears of what its neighbours sent at a step."""

    name: ClassVar[str]
    draws: ClassVar[bool]  # it draws events per arc from the seed's keyed streams (its state holds keys and step)
    holds: ClassVar[bool]  # receivers keep copies of what they heard (late, asleep or compressed messages)

    def init(self, seeds: int, arcs: Arcs, seed: int = 0):
        """Its state at step 0 for ``seeds`` seeds of base seed ``seed`` over ``arcs``: the counts at zero."""
        ...

    def deliver(self, state, arcs: Arcs, sent: dict, up: np.ndarray | None):
        """(the step's `dgtd.channels.Inbox`, the new state) from what every agent sent (name -> (B, N, q)) and the
        edges up (B, E) (None: every edge)."""
        ...

    def share(self, arc_ids: np.ndarray, agents: np.ndarray) -> Channel:
        """The channel over the arcs ``arc_ids`` and agents ``agents`` (ids in the whole network) of an MPI rank."""
        ...

    def mean_mixing(self, network, arcs: Arcs, mixing: str):
        """E of the Laplacian an algorithm mixing by ``mixing`` ("laplacian" or "metropolis") applies to what it
        hears, (N, N)."""
        ...

    def describe(self) -> str:
        """What it does to messages, for a run's header."""
        ...


def copied(state):
    """A state of its own: arrays not shared with ``state`` (a channel may update its messages in flight in place)."""
    return type(state)(*(np.array(x) for x in state))


def per_arc_fields(state) -> dict:
    """The fields of a channel's state (a NamedTuple, or a dict of its fields) that hold one entry per arc: those
    (B, arcs, ...) with arcs > 0; a field of an arcs axis of size 0 (no slots for late messages) holds none."""
    fields = state if isinstance(state, dict) else state._asdict()
    B = np.shape(fields["messages"])[0]
    return {name: x for name, x in fields.items() if np.ndim(x) >= 2 and np.shape(x)[0] == B and np.shape(x)[1]}


def counted(state, arrived: np.ndarray, messages: int, numbers: int):
    """``state`` with the counts of ``arrived`` (B,) arcs added, each of which delivered ``messages`` messages of
    ``numbers`` numbers in all, in full (whole numbers: the same floats in any order; the compiled driver adds a
    block's at once, the NumPy channels a step's)."""
    return state._replace(
        messages=state.messages + arrived * messages, bits=state.bits + arrived * (numbers * BITS_PER_NUMBER)
    )
