"""This computer's clock against the autopilot's GPS time.

The fleet's clocks must agree: the ground station refuses every datagram more than its
``clock_tolerance_s`` (30 s) off its own clock, and the drone refuses the station's the same
way (docs/protocol.md). A Raspberry Pi has no real-time clock; without NTP in the field it
boots at the time it last saved, and its drone was refused whole while its log said nothing.
The autopilot knows the time from its GPS (SYSTEM_TIME), so the companion can tell.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

from companion.telemetry import Sample, SystemTimeSample

__all__ = ["CLOCK_OFF_S", "ClockCheck", "clock_problem"]

log = logging.getLogger("companion.clock")

CLOCK_OFF_S = 10.0
"""Further than this from the autopilot's GPS time is told: a third of the station's 30 s,
and well beyond ArduCopter SITL's GPS time, 3.2 s behind its host's clock (measured)."""
GPS_ERA_S = 1.6e9
"""A UTC time before 2020 is an autopilot's own counter, not GPS time (ArduPilot sends 0
until its GPS has the time; a board's RTC without a battery starts near 1970)."""
TELL_EVERY_S = 600.0


def clock_problem(local_s: float, autopilot_unix_s: float | None) -> str | None:
    """What is wrong with this computer's clock ``local_s``, read when the autopilot said
    ``autopilot_unix_s``; None when it agrees (or the autopilot has no GPS time)."""
    if autopilot_unix_s is None or autopilot_unix_s < GPS_ERA_S:
        return None
    off = local_s - autopilot_unix_s
    if abs(off) <= CLOCK_OFF_S:
        return None
    side = "behind" if off < 0 else "ahead of"
    return (f"this computer's clock is {abs(off):.0f} s {side} the autopilot's GPS time: the "
            "ground station refuses every datagram more than its clock_tolerance_s (30 s) "
            "off its own clock; set the clock (chrony or gpsd with the GPS, NTP, or "
            "`date -s`)")


class ClockCheck:
    """Listens to the telemetry; says a clock that is off once, then every ten minutes, and
    when it agrees again (chrony stepped it)."""

    def __init__(self, monotonic: Callable[[], float]) -> None:
        self._monotonic = monotonic
        self._told_at: float | None = None
        self.off = False

    def on_sample(self, sample: Sample) -> None:
        if not isinstance(sample, SystemTimeSample) or sample.unix_time_s is None:
            return
        if sample.unix_time_s < GPS_ERA_S:
            return
        problem = clock_problem(sample.t, sample.unix_time_s)
        now = self._monotonic()
        if problem is None:
            if self.off:
                log.info("clock: this computer's clock agrees with the autopilot's GPS time "
                         "again (%+.1f s)", sample.t - sample.unix_time_s)
            self.off, self._told_at = False, None
            return
        self.off = True
        if self._told_at is None or now - self._told_at >= TELL_EVERY_S:
            self._told_at = now
            log.warning("clock: %s", problem)
