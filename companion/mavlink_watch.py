"""Notices, while the autopilot's HEARTBEAT goes on, that its telemetry must be asked for again.

The link-loss timeout alone misses two things a field operator meets:

* **An autopilot that reboots faster than ``heartbeat_timeout_s``.** ArduCopter 4.5 SITL sent
  its next HEARTBEAT 2.1 s after MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN (docs/companion.md); on
  TCP the closed socket told the companion, on a UART or UDP nothing does. The rebooted
  ArduPilot streams nothing but HEARTBEAT until asked and PX4 streams its defaults again
  (the companion's rates and ``HIGHRES_IMU = 0`` gone), its fix and EKF origin are new, yet
  the companion kept the old fix and never asked again: the dashboard showed the last
  position, struck through, and the pre-reboot "3D fix" for the rest of the flight.
  A message's ``time_boot_ms`` going back says the autopilot started again.
* **Streams that stop** while HEARTBEATs arrive: that reboot on ArduPilot (nothing carries
  ``time_boot_ms`` until streams are asked for again), or a GCS on the same link turning
  streams off with REQUEST_DATA_STREAM. After ``silence_s`` without any wanted message the
  companion asks again; it never re-asks while they flow, so it does not fight a GCS over
  rates (one that slows a stream slows it; the companion only restarts a stopped link).

Also here: which streams to ask each autopilot family for (:func:`streams_for`), and how
long the reader did not look at the link (:func:`stalled_s`). Sans-I/O: the reader
thread feeds them messages and the time.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

__all__ = ["BOOT_CLOCK_MESSAGES", "REBOOT_TOLERANCE_MS", "STALL_SLACK_S", "StreamWatch",
           "stalled_s", "streams_for"]

REBOOT_TOLERANCE_MS = 1000
"""``time_boot_ms`` may step back this much without meaning a reboot (messages of one
autopilot share its clock; a little slack for one stamped before another was sent)."""

STALL_SLACK_S = 1.0
"""A receive round may take pymavlink's wait (up to 1.5 times the receive timeout) and this
much more; a longer gap between two receives is time the reader did not run."""

BOOT_CLOCK_MESSAGES = frozenset({"SYSTEM_TIME", "ATTITUDE", "GLOBAL_POSITION_INT"})
"""Whose ``time_boot_ms`` is read: ones the companion asks for and both stacks stamp with
their boot clock. Others are not trusted with it (a stack may leave a field it does not
fill at 0, which would read as a reboot at every such message)."""


@dataclass(kw_only=True)
class StreamWatch:
    """The autopilot's boot clock and when a wanted stream message last arrived."""

    silence_s: float
    """Wanted streams silent this long (HEARTBEATs arriving) means: ask again."""
    wanted: frozenset[str] = field(default_factory=frozenset)
    boot_ms: int | None = None
    t_last_stream: float | None = None
    """When a wanted message last arrived, or the streams were last asked for."""
    told: bool = False
    """The current silence was logged (a WARNING once, then DEBUG per request)."""

    def asked(self, names: Iterable[str], rates_hz: Iterable[float], now: float) -> None:
        """The streams were (re)requested at ``now``: only those with a rate are awaited."""
        self.wanted = frozenset(n for n, r in zip(names, rates_hz, strict=True) if r > 0)
        self.t_last_stream = now

    def rebooted(self, msg: Any, now: float) -> str | None:
        """Feed one message of the autopilot (its system and component); a reason when its
        ``time_boot_ms`` went back, i.e. it booted again."""
        if msg.get_type() in self.wanted:
            self.t_last_stream = now
            self.told = False
        if msg.get_type() not in BOOT_CLOCK_MESSAGES:
            return None
        boot_ms = getattr(msg, "time_boot_ms", None)
        if not isinstance(boot_ms, int):
            return None
        last, self.boot_ms = self.boot_ms, boot_ms
        if last is not None and boot_ms + REBOOT_TOLERANCE_MS < last:
            return (f"autopilot rebooted (time since boot went back from {last / 1e3:.1f} s "
                    f"to {boot_ms / 1e3:.1f} s)")
        return None

    def silent(self, now: float) -> bool:
        """True when wanted streams were asked for and none arrived for ``silence_s``."""
        return (bool(self.wanted) and self.t_last_stream is not None
                and now - self.t_last_stream > self.silence_s)


def stalled_s(last_look: float | None, now: float, recv_timeout_s: float) -> float:
    """How long the reader did not look between its receives at ``last_look`` and ``now``
    (its machine stalled: swap, an SD card's write, a paused VM; or the clock stepped
    forward), 0.0 when it ran; negative when the clock stepped back. The link's timers move
    by it: none of that time is the link's silence (a first message read after a stall, not
    a HEARTBEAT, made it "no HEARTBEAT for 9.8 s" against a 3 s timeout with the HEARTBEATs
    waiting in the buffer), and a clock set back an hour (a Pi without a real-time clock
    syncing) must not hide a lost link for that hour."""
    if last_look is None:
        return 0.0
    gap = now - last_look
    return gap if gap < 0 or gap - 1.5 * recv_timeout_s > STALL_SLACK_S else 0.0


FAMILY_ONLY_STREAMS = {"EKF_STATUS_REPORT": "ardupilot", "ESTIMATOR_STATUS": "px4"}
"""Messages one autopilot family has and the other lacks. ArduCopter 4.5 answers a request
for ESTIMATOR_STATUS DENIED with a STATUSTEXT ("No ap_message for mavlink id (230)") that
would become the drone's latest status text on the dashboard at every connection."""


def streams_for(autopilot: str | None, rates_hz: Mapping[str, float]) -> dict[str, float]:
    """The streams worth asking ``autopilot`` for (an unknown family: all of them)."""
    return {name: rate for name, rate in rates_hz.items()
            if FAMILY_ONLY_STREAMS.get(name, autopilot) == autopilot
            or autopilot not in ("ardupilot", "px4")}
