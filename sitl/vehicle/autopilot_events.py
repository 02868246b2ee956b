"""What the simulated flight controller says back: command results, events, guided targets.

Plain data shared by the flight controller (:mod:`sitl.vehicle.autopilot`), its guidance
(:mod:`sitl.vehicle.guidance`) and the MAVLink layer (:mod:`sitl.vehicle.core`).
"""

from __future__ import annotations

from dataclasses import dataclass

from sitl.vehicle.flavour import Mode

# MAV_RESULT
ACCEPTED = 0
TEMPORARILY_REJECTED = 1
DENIED = 2
UNSUPPORTED = 3
FAILED = 4

# MAV_SEVERITY
SEV_CRITICAL = 2
SEV_WARNING = 4
SEV_NOTICE = 5
SEV_INFO = 6

Vec3 = tuple[float, float, float]

PREARM_FIRST_REPORT_S = 2.0
PREARM_REPORT_PERIOD_S = 30.0
"""ArduPilot reports failing pre-arm checks ("PreArm: ...") every 30 s while disarmed."""


class AutopilotEvent:
    """Base of the events the flight controller reports. Don't subclass these elsewhere."""


@dataclass(frozen=True, slots=True, kw_only=True)
class ModeChanged(AutopilotEvent):
    mode: Mode


@dataclass(frozen=True, slots=True, kw_only=True)
class ItemReached(AutopilotEvent):
    seq: int


@dataclass(frozen=True, slots=True, kw_only=True)
class CurrentItemChanged(AutopilotEvent):
    seq: int


@dataclass(frozen=True, slots=True, kw_only=True)
class FixAcquired(AutopilotEvent):
    """GPS fix and estimator origin: home is set, positions become valid."""


@dataclass(frozen=True, slots=True, kw_only=True)
class HomeChanged(AutopilotEvent):
    """DO_SET_HOME moved home (the estimator origin stays)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class StatusText(AutopilotEvent):
    severity: int
    text: str


@dataclass(frozen=True, slots=True, kw_only=True)
class CommandResult:
    """MAV_RESULT of a command and, on refusal, the STATUSTEXT that explains it."""

    result: int
    text: str | None = None

    @property
    def ok(self) -> bool:
        return self.result == ACCEPTED


@dataclass(frozen=True, slots=True, kw_only=True)
class GuidedTarget:
    """A SET_POSITION_TARGET_* in local NED: position or velocity (position wins), yaw."""

    position_ned_m: Vec3 | None = None
    velocity_ned_m_s: Vec3 | None = None
    yaw_rad: float | None = None
    t_s: float = 0.0

