"""A planning margin learned from the fleet's overshoot of its budget (issue 18).

Each agent plans the fleet's window from the sends it knows of; the others' sends reach it
only when they are delivered, and under a queue that is a second or more later. Drones whose
frames are generated within milliseconds of each other then each see room in the window
and fill it: the fleet overshoots ξ·T (56 window violations in a 20 s image run, none known
to the deciding agent), and the room the plan had left for small reports is gone when they
are generated. More search does not help; planning against a smaller budget does.

Once every send of a window has had time to arrive (its end is older than the high
latency), the agent knows the fleet's sends in it. A window above the budget raises the
margin by the share it overshot; a window below ``1 - slack`` of the planning budget lowers
it slowly. The optimiser plans with ``budget · (1 - margin)``. Sans-I/O: times are arguments.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

__all__ = ["OvershootMargin"]


@dataclass(slots=True)
class OvershootMargin:
    """Share of the budget kept free for the fleet's sends that the agent does not know yet."""

    up: float = 0.5
    """Per observed window: margin += up · overshoot share (e.g. 10 % over: +5 points)."""
    down: float = 0.01
    """Per observed window well under the planning budget: margin -= down."""
    slack: float = 0.15
    """A window counts as "under" below (1 - slack) of the planning budget."""
    ceiling: float = 0.6
    margin: float = 0.0
    _last_end: float = float("-inf")

    def observe(self, sends: Iterable[tuple[float, int]], *, now: float, settle_s: float,
                window_s: float, budget_bytes: float) -> None:
        """Update from the window ending ``settle_s`` before ``now`` (whose sends are all
        known by now); each window end is used at most once per ``window_s / 4``."""
        end = now - settle_s
        if budget_bytes <= 0 or end < self._last_end + window_s / 4:
            return
        self._last_end = end
        used = sum(b for t, b in sends if end - window_s < t <= end)
        over = used / budget_bytes - 1.0
        if over > 1e-9:
            self.margin = min(self.ceiling, self.margin + self.up * over)
        elif used < (1.0 - self.slack) * (1.0 - self.margin) * budget_bytes:
            self.margin = max(0.0, self.margin - self.down)

    def plan_budget(self, budget_bytes: float) -> float:
        return budget_bytes * (1.0 - self.margin)
