"""The fleet's budget before an agent has heard of its peers (issue 18, round 7).

Each agent plans the fleet's window from the sends it knows of. At the mission start it
knows of none: every drone took the whole window for itself, and the four first frames of
the image study (160 kB at t = 0.00-0.03 s) landed in one 62.5 kB window at 25 kB/s, a
third of the bytes MCTS delivered in 20 s. Until it has heard of a peer, an agent assumes
that peer takes its equal share of the budget (the peers the mission declares, ``fleet``),
for at most ``for_s`` after its first decision (a peer that never sends must not shrink
the budget for ever).
"""

from __future__ import annotations

__all__ = ["start_share"]


def start_share(budget_bytes: float, *, fleet: int | None, heard: int, elapsed_s: float,
                for_s: float, ramp_s: float | None = None) -> float:
    """The part of ``budget_bytes`` this agent plans with: the whole budget less an equal
    share for each of the ``fleet - 1 - heard`` peers it has not heard of, while
    ``elapsed_s <= for_s``; the whole budget otherwise or without a declared ``fleet``."""
    if fleet is None or fleet <= 1 or elapsed_s > for_s:
        return budget_bytes
    unheard = max(0, fleet - 1 - heard)
    share = budget_bytes * (fleet - unheard) / fleet
    if ramp_s:
        share *= min(1.0, 1.0 / fleet + elapsed_s / ramp_s)
    return share
