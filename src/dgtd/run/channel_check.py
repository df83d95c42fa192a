"""`check_channel`: what a link model must do for the run loop, the checkpoints and the MPI runtime, checked on a
user's own (as `dgtd.check_algorithm` does for algorithms), each finding one line.

A link model follows `dgtd.channels.base.Channel` and nothing more: a frozen dataclass with ``name``, ``draws``,
``holds``, ``init``, ``deliver``, ``share``, ``mean_mixing`` and ``describe``, over a NamedTuple state holding the
counts ``messages`` and ``bits`` (B,) and whatever else it carries, per seed (B, ...) or per seed and arc
(B, arcs, ...). The check runs it on a network (by default a ring of 6 with chords whose links are up with
probability 0.6), on messages of two names, for `STEPS` steps, then through a short DGTD run on the NumPy reference.
"""

from __future__ import annotations

import numpy as np

from dgtd.channels.arcs import Arcs
from dgtd.channels.base import copied
from dgtd.channels.inbox import Inbox
from dgtd.graphs import topologies
from dgtd.graphs.random import random_edges
from dgtd.run.conformance import finding

STEPS = 20  # steps delivered by hand
SEEDS, Q = 2, 3  # seeds, and numbers per message
PROTOCOL = ("name", "draws", "holds", "init", "deliver", "share", "mean_mixing", "describe")


def check_channel(channel, network=None) -> dict:
    """Check ``channel`` (an instance of a link model) over ``network`` (a `dgtd.random_edges`; default a ring of 6
    with chords, links up with probability 0.6: give your own where the channel's parameters are per arc or agent)
    against the protocol, and raise AssertionError, one line
    saying what it breaks: a missing part; a state that is not a NamedTuple with ``messages`` and ``bits`` (B,) and
    fields per seed or per seed and arc; a ``deliver`` that changes what was sent, returns another kind of state,
    an `Inbox` whose ``heard`` is not (B, arcs) in [0, 1], counts that fall, or other numbers
    for the same input; a ``mean_mixing`` that is not (N, N) with rows summing to 0; a ``describe`` that is not one
    line; a run on it that raises. Returns {"arcs", "steps", "messages"}: the arcs, the steps delivered, the messages
    counted.

    Example::

        >>> import dgtd
        >>> dgtd.check_channel(dgtd.Lossy(0.3))  # doctest: +SKIP
    """
    missing = [part for part in PROTOCOL if not hasattr(channel, part)]
    if missing:
        raise AssertionError(f"{_name(channel)} lacks {', '.join(missing)} of the link-model protocol (dgtd.Channel)")
    network = network if network is not None else random_edges(topologies.ring_with_chords(6, 2), 0.6)
    arcs = Arcs.of(network.base.edges, network.n_nodes)
    state = _call(channel, "init(2 seeds, arcs, seed 3)", channel.init, SEEDS, arcs, 3)
    _check_state(channel, state, arcs, "init")
    rng = np.random.default_rng(0)
    for k in range(STEPS):
        sent = {name: rng.normal(size=(SEEDS, arcs.n_agents, Q)) for name in ("w", "theta")}
        up = rng.random((SEEDS, network.n_edges)) < network.p
        state = _step(channel, state, arcs, sent, up, k)
    _check_mixing(channel, network, arcs)
    described = _call(channel, "describe()", channel.describe)
    if not isinstance(described, str) or not described.strip() or "\n" in described:
        raise AssertionError(f"{_name(channel)}'s describe() must return one line of text, got {described!r}")
    _call(channel, "share(every arc, every agent)", channel.share, np.arange(arcs.n_arcs), np.arange(arcs.n_agents))
    _run(channel, network)
    return {"arcs": arcs.n_arcs, "steps": STEPS, "messages": float(np.sum(state.messages))}


def _name(channel) -> str:
    return str(getattr(channel, "name", type(channel).__name__))


def _call(channel, what: str, function, *args):
    try:
        return function(*args)
    except (AssertionError, KeyboardInterrupt):
        raise
    except Exception as e:  # noqa: BLE001  (the user's link model failing: theirs to see, in one line)
        raise finding(channel, what, e) from e


def _check_state(channel, state, arcs: Arcs, where: str) -> None:
    fields = getattr(state, "_fields", None)
    if fields is None:
        raise AssertionError(f"{_name(channel)}'s {where} returned a {type(state).__name__}, not a NamedTuple")
    for name in ("messages", "bits"):
        if name not in fields or np.shape(getattr(state, name)) != (SEEDS,):
            raise AssertionError(
                f"{_name(channel)}'s state after {where} has no {name} of shape (B,) = ({SEEDS},): every state "
                "holds the counts messages and bits per seed"
            )
    for name, x in zip(fields, state):
        if np.size(x) and (np.ndim(x) == 0 or np.shape(x)[0] != SEEDS):  # (an empty field: a slot it does not use)
            raise AssertionError(
                f"{_name(channel)}'s state field {name} after {where} has the shape {np.shape(x)}: a field is per "
                f"seed (B, ...) or per seed and arc (B, arcs, ...), B = {SEEDS}"
            )


def _step(channel, state, arcs: Arcs, sent: dict, up: np.ndarray, k: int):
    """One delivery, checked: what it returns, what it left alone, and the same again for the same input. (It may
    update the state it is given in place: the backends hand it a copy of its own, `copied`, at every block.)"""
    given = {name: x.copy() for name, x in sent.items()}
    where = f"deliver (step {k})"
    result = _call(channel, where, channel.deliver, copied(state), arcs, sent, up)
    if not (isinstance(result, tuple) and len(result) == 2 and isinstance(result[0], Inbox)):
        raise AssertionError(f"{_name(channel)}'s deliver must return (an Inbox, the new state)")
    inbox, new = result
    if any(not np.array_equal(given[name], sent[name]) for name in sent):
        raise AssertionError(f"{_name(channel)}'s deliver changed what the agents sent (step {k})")
    if type(new) is not type(state):
        raise AssertionError(
            f"{_name(channel)}'s deliver returned a {type(new).__name__}, not the {type(state).__name__} it was "
            f"given (step {k})"
        )
    _check_state(channel, new, arcs, where)
    heard = np.asarray(inbox.heard)
    if heard.shape != (SEEDS, arcs.n_arcs) or not np.all((heard >= 0) & (heard <= 1)):
        raise AssertionError(
            f"{_name(channel)}'s inbox heard has the shape {heard.shape} or values outside [0, 1]: it is (B, arcs) "
            f"= ({SEEDS}, {arcs.n_arcs}), 1 where an arc delivered"
        )
    if np.any(np.asarray(new.messages) < np.asarray(state.messages)) or np.any(np.asarray(new.bits) < state.bits):
        raise AssertionError(f"{_name(channel)}'s counts of messages or bits fell at step {k}")
    again = _call(channel, where, channel.deliver, copied(state), arcs, sent, up)[1]
    if any(not np.array_equal(a, b, equal_nan=True) for a, b in zip(new, again)):
        raise AssertionError(
            f"{_name(channel)}'s deliver gave other numbers for the same state and input (step {k}): draw from the "
            "keyed streams (dgtd.streams) by seed, step and arc, not from a generator of its own"
        )
    return new


def _check_mixing(channel, network, arcs: Arcs) -> None:
    for mixing in ("laplacian", "metropolis"):
        L = np.asarray(_call(channel, f"mean_mixing({mixing!r})", channel.mean_mixing, network, arcs, mixing))
        N = arcs.n_agents
        if L.shape != (N, N) or not np.isfinite(L).all() or np.abs(L.sum(axis=1)).max() > 1e-9:
            raise AssertionError(
                f"the rows of mean_mixing({mixing!r}) of {_name(channel)} must sum to 0 in an ({N}, {N}) matrix "
                "(E of the Laplacian an agent mixes with over what it hears)"
            )


def _run(channel, network) -> None:
    """300 steps of DGTD on a random problem of the network's agents through the channel, on the NumPy reference:
    finite."""
    from dgtd.algorithms import DGTD
    from dgtd.problems.generators import random_problem
    from dgtd.run.loop import RunSettings, run
    from dgtd.sources.model import Sampling

    problem = random_problem(5, network.n_nodes, 3, np.random.default_rng(2))
    settings = RunSettings(iterations=300, seeds=SEEDS, checkpoints=3, block_size=97, backend="numpy")

    def through():
        return run(problem, network, DGTD(alpha0=1.0), Sampling(), settings, channel=channel)

    result = _call(channel, "a run of DGTD through it", through)
    if not np.isfinite(result.w_last).all():
        raise AssertionError(f"{_name(channel)}: a run of DGTD through it ended with estimates that are not finite")
