"""Drones refused for their clock, named with how far off it is.

A datagram whose ``t_sent`` is further than ``clock_tolerance_s`` from the station's clock is
refused (``stale``, docs/protocol.md). A Raspberry Pi has no real-time clock: without NTP in
the field it boots at the time it last saved, minutes to days behind, and the station refused
every datagram of that drone. The dashboard showed no tile for it and an alert
"datagrams dropped (stale)" naming nobody; the station's log said nothing.
"""

from __future__ import annotations

import logging

__all__ = ["TELL_EVERY_S", "ClockWatch"]

log = logging.getLogger("ground_station.clock")

TELL_EVERY_S = 60.0
"""A drone that stays refused is told again this often."""


class ClockWatch:
    """Which drones are refused for their clock, and when that was last said."""

    def __init__(self, tolerance_s: float) -> None:
        self.tolerance_s = tolerance_s
        self._told: dict[str, float] = {}

    def refused(self, drone: str, skew_s: float, now: float) -> str | None:
        """The text to tell for a refused datagram of ``drone`` (its clock minus ours is
        ``skew_s``), or None when it was told less than :data:`TELL_EVERY_S` ago."""
        told = self._told.get(drone)
        if told is not None and now - told < TELL_EVERY_S:
            return None
        if len(self._told) >= 1024:  # senders are authenticated, but keep it bounded
            self._told.clear()
        self._told[drone] = now
        side = "behind" if skew_s < 0 else "ahead of"
        text = (f"datagrams refused: its clock is {abs(skew_s):.0f} s {side} this station's "
                f"(clock_tolerance_s = {self.tolerance_s:g}): set the drone's clock (NTP, or "
                "chrony with the autopilot's GPS time), or this computer's")
        log.warning("%s: %s", drone, text)
        return text
