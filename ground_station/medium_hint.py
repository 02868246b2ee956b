"""A station that does not hear the medium its drones share their status on.

Seen on a netns fleet (docs/peers.md, by hand): three drones on ``peers.medium`` with the
spec ``peer_sharing`` (position and status to ``["ground", "peers"]``: sent once, on the
medium), the station run without ``shared_medium``: the dashboard showed every drone with
its images but mode "–", no peers row and no autopilot state, and nothing in the station's
log said why. Sans-I/O: :class:`~ground_station.fleet.FleetView` feeds it every message and
asks it at each tick.
"""

from __future__ import annotations

import logging

__all__ = ["UNHEARD_AFTER_S", "StatusUnheard"]

log = logging.getLogger(__name__)

UNHEARD_AFTER_S = 30.0
"""A drone heard this long without one status message is told about (the companion sends
one every ``telemetry.status_period_s``, 1 s by default)."""


class StatusUnheard:
    """Per drone: the first message's time, until its first status; one WARNING per drone."""

    def __init__(self, *, medium: str | None = None, after_s: float = UNHEARD_AFTER_S) -> None:
        self.medium = medium
        """The station's ``shared_medium`` (None: it hears none)."""
        self.after_s = after_s
        self._first: dict[str, float] = {}
        self._done: set[str] = set()

    def on_message(self, drone: str, type_: str, now: float) -> None:
        if drone in self._done:
            return
        if type_ == "status":
            self._done.add(drone)
            self._first.pop(drone, None)
        else:
            self._first.setdefault(drone, now)

    def check(self, now: float) -> list[tuple[str, str]]:
        """(drone, text) for each drone heard ``after_s`` without a status; logged once."""
        told = []
        for drone, first in list(self._first.items()):
            if now - first < self.after_s:
                continue
            ours = ("" if self.medium is None else f" (this station's is {self.medium!r}: "
                    "not the one the drone sends on?)")
            text = (f"{now - first:.0f} s of messages from {drone} and no status: a fleet that "
                    "shares status with its peers sends it on the shared medium only; set "
                    f"shared_medium to the drones' peers.medium{ours} (docs/peers.md), or give "
                    "the mission spec a status type")
            log.warning(text)
            told.append((drone, text))
            self._done.add(drone)
            del self._first[drone]
        return told
