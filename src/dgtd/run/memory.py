"""What a run will hold in memory, estimated before anything is allocated, against what the machine has free."""

from __future__ import annotations

import os
from pathlib import Path

from dgtd.errors import DgtdInputError

BYTES = 8  # every array of a run holds float64
TRACE_MAX, SUM_TRACE_MAX = 2_000_000, 20_000_000  # numbers: the run loop keeps its traces only up to these sizes


def available_bytes() -> int | None:
    """The memory free for a new process: MemAvailable of /proc/meminfo, else the physical memory, else None."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None


def run_bytes(algorithm, seeds: int, agents: int, features: int, arcs: int, checkpoints: int, backend: str) -> int:
    """About how many bytes a run holds at once (Python integers: no overflow whatever the sizes).

    Per seed, agent and feature: the algorithm's state twice (the state and the next one, or the compiled driver's
    own copy), its messages twice (the double buffer), the running sum of w, its copy at the tail's start and a
    row of work; the reference backend also forms each message's differences over the arcs. Per checkpoint: the
    metrics of every seed and the errors of every agent, and the traces of w and of its sum where the loop keeps
    them (up to `TRACE_MAX` and `SUM_TRACE_MAX` numbers)."""
    state = len(algorithm.init(1, 1, 1))
    messages = len(algorithm.messages)
    cells = seeds * agents * features
    numbers = cells * (2 * state + 2 * messages + 3)
    if backend in ("numpy", "jax"):  # they form each message's differences over the arcs
        numbers += seeds * arcs * features * 2 * messages
    numbers += checkpoints * seeds * (16 + 2 * agents)
    trace = checkpoints * cells
    numbers += (trace if trace <= TRACE_MAX else 0) + (trace if trace <= SUM_TRACE_MAX else 0)
    return BYTES * numbers


def check_memory(
    algorithm,
    seeds: int,
    agents: int,
    features: int,
    arcs: int,
    checkpoints: int,
    backend: str,
    ranks: int = 1,
    here: int = 1,
    free: int | None = -1,
) -> None:
    """Refuse, in one line with the estimate and the most seeds that fit, a run that needs more memory than the
    machine has ``free`` (default: `available_bytes`; None: unknown, no check). Agents spread over ``ranks`` ranks: a
    rank holds its share of them and of their arcs (N / R, rounded up), and the ``here`` ranks on this machine need
    that share each, together."""
    free = available_bytes() if free == -1 else free
    own, own_arcs = -(-agents // ranks), -(-arcs // ranks)
    need = here * run_bytes(algorithm, seeds, own, features, own_arcs, checkpoints, backend)
    if free is None or need <= free:
        return
    fit = free // (here * run_bytes(algorithm, 1, own, features, own_arcs, checkpoints, backend))
    lower = (
        f"lower --seeds to at most {fit:,}"
        if fit >= 1
        else "a single seed does not fit: fewer agents or features, or --checkpoints lower"
        + (", or more machines for the ranks" if ranks > 1 else "")
    )
    size = f"{seeds:,} seeds x {agents:,} agents x {features:,} features"
    who = (
        "this run needs" if ranks == 1 else "this rank needs" if here == 1 else f"the {here} ranks on this machine need"
    )
    share = "" if ranks == 1 else f", {own:,} agents a rank of {ranks}"
    raise DgtdInputError(
        f"{who} about {need / 1e9:,.1f} GB ({size}{share}), more than the {free / 1e9:,.1f} GB free on this "
        f"machine; {lower}"
    )


PROBE_FROM = 100_000  # agents from which a generated task's memory is measured before it is built
PROBE_AGENTS = (200, 400)  # the sizes it is built at for that: its bytes a agent are their difference's


def array_bytes(obj, seen: set | None = None) -> int:
    """The bytes of the NumPy arrays ``obj`` holds: itself, its attributes, tuples, lists and dicts, recursively,
    each array counted once."""
    import numpy as np

    seen = set() if seen is None else seen
    if id(obj) in seen or obj is None or isinstance(obj, (str, bytes, int, float, bool)):
        return 0
    seen.add(id(obj))
    if isinstance(obj, np.ndarray):
        return obj.nbytes if obj.base is None or id(obj.base) not in seen else 0
    if isinstance(obj, (tuple, list)):
        return sum(array_bytes(x, seen) for x in obj)
    held = obj if isinstance(obj, dict) else getattr(obj, "__dict__", {})
    return sum(array_bytes(x, seen) for x in held.values())


def probed_bytes(make, n_agents: int, built=None) -> int | None:
    """About the bytes of ``make(n_agents)``, a generated task, from two small builds (`PROBE_AGENTS`; ``built``, the
    caller's own build at the smaller size, where it has one): its arrays' bytes linear in the agents (every
    generated task here holds rows per agent, and per link of a sparse graph); None where the small builds are
    refused (a task that cannot have that many agents refuses the large one too)."""
    small, large = PROBE_AGENTS
    try:
        a, b = array_bytes(make(small) if built is None else built), array_bytes(make(large))
    except DgtdInputError:
        return None
    return int(a + max(b - a, 0) * (n_agents - small) / (large - small))


def check_task_memory(what: str, need: int, lower: str, free: int | None = -1) -> None:
    """Refuse, in one line, a task that needs more memory than is free, before it is built."""
    free = available_bytes() if free == -1 else free
    if free is not None and need > free:
        raise DgtdInputError(
            f"{what} needs about {need / 1e9:,.1f} GB, more than the {free / 1e9:,.1f} GB free on this machine "
            f"(measured on the task built at {PROBE_AGENTS[0]} and {PROBE_AGENTS[1]} agents); {lower}"
        )
