"""Which interval of a set of mission logs to evaluate, and why.

A log's ``{"mission": ...}`` records mark intervals: a ``t_start`` opens one, a ``t_end``
closes the open one. A later ``t_start`` while one is open replaces it (the ground station
marks the mission when it is created, then again when ``start`` runs; a companion marks its
process start and then the mission). An end with nothing open marks an interval whose start
is unknown (``--t-start``, else 0).

The logs disagree on purpose: a receiver's log (one that holds received copies: the ground
station's) marks the mission as commanded, a sender's log (a drone's) marks its process's
lifetime. The receiver's intervals are therefore preferred; a sender's are used only when no
receiver log has one. Several candidates are listed and the last complete one is the
default; ``--mission N|last|all`` chooses.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

__all__ = ["MissionInterval", "Selection", "intervals_of", "select_intervals"]


@dataclass(frozen=True, slots=True)
class MissionInterval:
    t_start: float | None
    t_end: float | None
    source: str
    """The log file it comes from."""

    @property
    def complete(self) -> bool:
        return self.t_start is not None and self.t_end is not None

    def describe(self) -> str:
        a = "?" if self.t_start is None else f"{self.t_start:.3f}"
        b = "open" if self.t_end is None else f"{self.t_end:.3f}"
        span = (f" ({self.t_end - self.t_start:.1f} s)"  # type: ignore[operator]
                if self.complete else "")
        return f"[{a}, {b}]{span} from {self.source}"


@dataclass(frozen=True, slots=True)
class Selection:
    chosen: list[MissionInterval]
    candidates: list[MissionInterval]
    why: str


def intervals_of(bounds: Sequence[tuple[float | None, float | None]], source: str,
                 kinds: Sequence[str | None] = ()) -> list[MissionInterval]:
    """The intervals one log's mission records mark, in file order. With the records'
    ``kinds`` (the ground station's), an operator's start while an operator's run is open
    goes on with that run, as the station's report does (``make demo`` starts its mission,
    then the operator presses start: the first part is the mission's too)."""
    out: list[MissionInterval] = []
    open_start: float | None = None
    open_kind: str | None = None
    for (t_start, t_end), kind in itertools.zip_longest(bounds, kinds[:len(bounds)]):
        if kind == "cancelled":  # that start never ran: the run it opened is no run
            if open_start == t_start:
                open_start = open_kind = None
        elif t_start is not None and t_end is not None:
            out.append(MissionInterval(t_start, t_end, source))
            open_start = None
        elif t_start is not None:
            if not (open_start is not None and open_kind == kind == "start"):
                open_start, open_kind = t_start, kind
        else:  # an end: closes the open interval, or marks one whose start is unknown
            out.append(MissionInterval(open_start, t_end, source))
            open_start = None
    if open_start is not None:
        out.append(MissionInterval(open_start, None, source))
    return out


def select_intervals(receiver_logs: Sequence[list[MissionInterval]],
                     sender_logs: Sequence[list[MissionInterval]], choice: str | None
                     ) -> Selection:
    """Pick the interval(s) to evaluate; ``choice`` is None, ``"last"``, ``"all"`` or a
    1-based number. Raises ValueError for a number out of range."""
    from_receivers = [i for log in receiver_logs for i in log]
    if from_receivers:
        candidates, whose = from_receivers, "the receiver's (ground station's) log"
    else:
        candidates = [i for log in sender_logs for i in log]
        whose = "the senders' logs (no receiver log has mission records)"
    unique: list[MissionInterval] = []
    seen: set[tuple[float | None, float | None]] = set()
    for interval in sorted(candidates, key=lambda i: (i.t_start is None, i.t_start or 0.0)):
        if (interval.t_start, interval.t_end) not in seen:
            seen.add((interval.t_start, interval.t_end))
            unique.append(interval)
    # a station restart closes a run and opens it again with the same start: [S, X] is then
    # the first part of [S, Y], one run, not two overlapping ones
    unique = [i for i in unique if not any(
        j.t_start == i.t_start and j.t_end is not None and i.t_end is not None
        and j.t_end > i.t_end for j in unique)]
    if not unique:
        return Selection([], [], "no mission records in the logs")
    if choice == "all":
        return Selection(unique, unique, f"all {len(unique)} mission intervals of {whose}")
    if choice is not None and choice != "last":
        number = int(choice)
        if not 1 <= number <= len(unique):
            raise ValueError(f"--mission {number}: the logs hold {len(unique)} mission "
                             f"interval(s), numbered 1..{len(unique)}")
        return Selection([unique[number - 1]], unique,
                         f"mission interval {number} of {len(unique)} (--mission {number})")
    if choice == "last":
        return Selection([unique[-1]], unique,
                         f"the last of {len(unique)} mission interval(s) (--mission last)")
    if len(unique) == 1:
        return Selection(unique, unique, f"the only mission interval, from {whose}")
    complete = [i for i in unique if i.complete]
    pick = complete[-1] if complete else unique[-1]
    number = unique.index(pick) + 1
    return Selection([pick], unique,
                     f"{len(unique)} mission intervals in {whose}; evaluating the last "
                     f"{'complete ' if complete else ''}one, number {number} "
                     "(choose with --mission N|last|all)")
