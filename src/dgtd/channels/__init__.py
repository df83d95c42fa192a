"""What arrives: the channel between the agents.

An algorithm says what each agent sends its neighbours at step k (`dgtd.algorithms.base.Algorithm.messages`,
``sends``); the network says which links are up (`dgtd.graphs`); the channel is the one object that turns the two
into what each agent hears, an `Inbox`, and keeps the count of messages and bits sent. It knows directions: a message
from j to i and one from i to j travel on separate arcs (`Arcs`), so that a link model can lose, delay or compress
one and not the other.

- `Perfect` (the default, and the paper's network, section 2.3): every link up at step k carries every message both
  ways, at once and exactly.
- `Lossy`: each message on arc j -> i is lost with the arc's own probability (`dgtd.channels.lossy`).
- `Imperfect`: `Lossy`'s links with late, asleep and compressed messages (`dgtd.channels.imperfect`).

Each follows `Channel` (`dgtd.channels.base`): its parameters, its own state, ``init`` / ``deliver``, its part over
an MPI rank's arcs (``share``) and its mean mixing, in its one file, with a compiled twin registered under its name
in `dgtd.backends.compiled.TWINS`, tested equal. A link model of one's own that follows `Channel` runs on
``--backend numpy`` (`dgtd.run(..., channel=...)`).
"""

from dgtd.channels.arcs import Arcs
from dgtd.channels.base import Channel, counted, per_arc_fields
from dgtd.channels.imperfect import HeldState, Imperfect
from dgtd.channels.inbox import Inbox
from dgtd.channels.lossy import LinkState, Lossy
from dgtd.channels.perfect import Counts, Perfect

CHANNELS = {cls.name: cls for cls in (Perfect, Lossy, Imperfect)}

__all__ = [
    "Arcs",
    "CHANNELS",
    "Channel",
    "Counts",
    "HeldState",
    "Imperfect",
    "Inbox",
    "LinkState",
    "Lossy",
    "Perfect",
    "counted",
    "per_arc_fields",
]
