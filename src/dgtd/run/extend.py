"""A finished run extended to more steps: `dgtd run --resume DIR -T LARGER` (and `dgtd learn`'s) goes on from the
state the run kept at its end (its last checkpoint, taken at T with ``--checkpoint-every``) where that state allows:
the same options but the steps, more of them, and nothing of the steps so far that a run of the new length would
have done otherwise (`dgtd.run.plan.run_steps` keeps the checkpoints measured). The samples and every link's draws
are keyed by their step, so the extended run's iterates are those of a run of the new length from its start."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from dgtd.errors import DgtdInputError
from dgtd.run.results import first_difference

STEPS = "iterations"


def extension(
    out: Path, saved: dict, record: dict, what: str, blocker: Callable[[int, int], str] = lambda T1, T2: ""
) -> int | None:
    """Where a run in ``out`` of the config ``saved`` kept its state at its end (its step its -T: the caller knows it)
    and ``record`` asks for more steps: the step it ended at, to go on from; None where it asks for no more (a
    finished run). Refused in one line: fewer steps than it took, another option changed beside -T, or what
    ``blocker(T1, T2)`` names (a reason the state kept does not allow it, '' where it does)."""
    T1, T2 = int(saved[STEPS]), int(record[STEPS])
    if T2 == T1:
        return None
    if T2 < T1:
        raise DgtdInputError(
            f"the {what} in {out} took {T1:,} steps already; -T {T2:,} would go back: give more steps to extend it, "
            "or --overwrite to start it afresh"
        )
    if diff := first_difference(*(_others(d) for d in (saved, record))):
        raise DgtdInputError(
            f"a finished {what} is extended by -T alone; {diff}: give only -T with --resume {out}, or start another run"
        )
    if why := blocker(T1, T2):
        raise DgtdInputError(f"the {what} in {out} cannot be extended from {T1:,} to {T2:,} steps: {why}")
    return T1


def without_state(out: Path, saved: dict, record: dict, what: str, command: str) -> None:
    """Refuse more steps for a finished run that kept no state at its end (it ran without --checkpoint-every);
    ``command`` starts it afresh (its options to follow)."""
    T1, T2 = saved.get(STEPS), record.get(STEPS)
    if T1 is not None and T2 is not None and int(T2) != int(T1):
        raise DgtdInputError(
            f"the {what} in {out} finished at {int(T1):,} steps without keeping its state (it ran without "
            f"--checkpoint-every), so -T {int(T2):,} cannot extend it: run it afresh with `{command} -T {int(T2)} "
            "--checkpoint-every K --overwrite` (a run with --checkpoint-every keeps its state at its end to go on from)"
        )


def other_length(out: Path, saved: dict, record: dict, what: str, command: str) -> None:
    """Refuse, naming how to extend it, a finished run's folder asked for the same run but its steps without
    --resume (``command`` its command, --resume DIR to follow)."""
    T1, T2 = saved.get(STEPS), record.get(STEPS)
    if T1 is None or T2 is None or int(T1) == int(T2):
        return
    if not first_difference(*(_others(d) for d in (saved, record))):
        raise DgtdInputError(
            f"{out} holds a finished {what} of {int(T1):,} steps; extend it with `{command} --resume {out} -T "
            f"{int(T2)}`, choose another --out, or pass --overwrite to replace it"
        )


def _others(record: dict) -> dict:
    """A record less its steps."""
    return {k: v for k, v in record.items() if k != STEPS}
