"""The fleet's budget at the mission start, before an agent has heard of its peers
(issue 18, round 7).

Each agent plans the fleet's window from the sends it knows of. At the mission start it
knows of none, so every drone took the whole window for itself: in the image study the four
first frames (160 kB at t = 0.00-0.03 s) went into one window of 62.5 kB at 25 kB/s, and
the drones' first position and battery reports, queued behind them on the shared channel,
arrived 1.1-1.2 s late. That cost MCTS about 6 % of the telemetry's utility (2 points of the
total) at every budget, and the frames a third of the bytes it delivered at 25 kB/s.

So, while a peer the mission declares (``fleet`` agents) has not been heard of, the agent
leaves it an equal share of the budget, and it ramps its own plan up from a ``1/fleet``
part over the first window (slow start: the first frames are small, the channel drains
before the reports come). Both end ``for_s`` after the first decision at the latest: a
peer that never sends must not shrink the budget for ever. The share never falls below
the smallest version of the message decided (``floor_bytes``): with ten agents and a budget
of a few messages per window (the fig. 5.7 fleet) 1/100 of it is less than any message, no
agent sent, none was heard, and the fleet was silent until ``for_s`` (uniform 5.5-12
msgs/T: 8-13 points lost).
"""

from __future__ import annotations

__all__ = ["start_share"]


def start_share(budget_bytes: float, *, fleet: int | None, heard: int, elapsed_s: float,
                window_s: float, for_s: float, floor_bytes: float = 0.0) -> float:
    """The part of ``budget_bytes`` the agent plans with ``elapsed_s`` after its first
    decision, having heard of ``heard`` of its ``fleet - 1`` peers: the budget less an
    equal share per unheard peer, times ``min(1, 1/fleet + elapsed_s/window_s)``, and at
    least ``floor_bytes`` (at most the budget). The whole budget without a declared
    ``fleet`` or after ``for_s``."""
    if fleet is None or fleet <= 1 or not elapsed_s <= for_s:
        return budget_bytes
    unheard = min(fleet - 1, max(0, fleet - 1 - heard))
    share = budget_bytes * (fleet - unheard) / fleet
    ramp = 1.0 / fleet + max(0.0, elapsed_s) / window_s if window_s > 0 else 1.0
    return max(share * min(1.0, ramp), min(floor_bytes, budget_bytes))
