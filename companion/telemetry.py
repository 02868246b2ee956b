"""Autopilot telemetry in SI units: the samples the MAVLink thread posts and the state they build.

The MAVLink reader (``companion.mavlink``) converts every message it receives into one of the
frozen samples below at once, in its own thread, stamped with the injected fleet clock
(``t``, seconds). Raw MAVLink scaled integers (degE7, mm, mV, cdeg) never travel past it.
:class:`TelemetryState` lives on the event loop thread and is only changed by
:meth:`TelemetryState.apply`, which the reader schedules with ``loop.call_soon_threadsafe``.
Unknown values are ``None`` (MAVLink's "not available" sentinels become ``None``).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

__all__ = [
    "AttitudeSample",
    "BatterySample",
    "CommandAckSample",
    "EstimatorSample",
    "GpsSample",
    "HeartbeatSample",
    "LinkStateSample",
    "ParamSample",
    "PositionSample",
    "Sample",
    "StatusTextSample",
    "SystemTimeSample",
    "TelemetrySnapshot",
    "TelemetryState",
]

GPS_FIX_3D = 3
"""GPS_FIX_TYPE_3D_FIX: the least fix a position may be reported with."""
NULL_ISLAND_DEG = 1e-6
ESTIMATOR_GRACE_S = 5.0
"""After the link comes up, a position waits this long for the estimator's first report; a
stack that sends none by then is judged by its GPS alone. The GPS fix and position come
first on a connection (ArduCopter 4.5 SITL streams both 33 s before its EKF uses the GPS)."""
"""|lat| and |lon| below this (about 0.1 m) are the 0/0 of an estimator without an origin."""


@dataclass(frozen=True, slots=True, kw_only=True)
class Sample:
    """Base of every telemetry sample; ``t`` is the fleet-clock time it was read (seconds)."""

    t: float


@dataclass(frozen=True, slots=True, kw_only=True)
class HeartbeatSample(Sample):
    """HEARTBEAT of the autopilot: the only confirmation of a mode change."""

    system_id: int
    autopilot: str
    """``ardupilot``, ``px4`` or ``generic``..."""
    vehicle_type: int
    """MAV_TYPE number (2 = quadrotor...)."""
    mode: str
    """Flight mode name as the autopilot family spells it (``GUIDED``, ``POSCTL``...)."""
    custom_mode: int
    base_mode: int
    armed: bool
    system_status: int


@dataclass(frozen=True, slots=True, kw_only=True)
class BatterySample(Sample):
    """SYS_STATUS or BATTERY_STATUS, whichever came; ``source`` says which."""

    source: str
    battery_v: float | None
    current_a: float | None
    battery_remaining: float | None
    """State of charge in 0..1."""


@dataclass(frozen=True, slots=True, kw_only=True)
class PositionSample(Sample):
    """GLOBAL_POSITION_INT (the fused position)."""

    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    alt_rel_m: float
    vn_m_s: float
    ve_m_s: float
    vd_m_s: float
    heading_deg: float | None


@dataclass(frozen=True, slots=True, kw_only=True)
class AttitudeSample(Sample):
    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    rollspeed_rad_s: float
    pitchspeed_rad_s: float
    yawspeed_rad_s: float


@dataclass(frozen=True, slots=True, kw_only=True)
class GpsSample(Sample):
    """GPS_RAW_INT (the receiver's own fix, before fusion)."""

    fix_type: int
    satellites: int | None
    lat_deg: float
    lon_deg: float
    alt_m: float
    eph_m: float | None
    """Horizontal dilution (HDOP) in metres-equivalent units as MAVLink reports it."""


@dataclass(frozen=True, slots=True, kw_only=True)
class EstimatorSample(Sample):
    """EKF_STATUS_REPORT (ArduPilot) or ESTIMATOR_STATUS (PX4): can the position be trusted?"""

    source: str
    flags: int
    """ESTIMATOR_STATUS_FLAGS (the same bits in both messages)."""
    position_ok: bool
    """An absolute horizontal position from an initialised estimator with an origin."""


@dataclass(frozen=True, slots=True, kw_only=True)
class SystemTimeSample(Sample):
    unix_time_s: float | None
    """Autopilot's UTC clock; ``None`` when it has none yet (0 on the wire)."""
    time_boot_s: float


@dataclass(frozen=True, slots=True, kw_only=True)
class StatusTextSample(Sample):
    severity: int
    """MAV_SEVERITY (0 emergency .. 7 debug)."""
    text: str


@dataclass(frozen=True, slots=True, kw_only=True)
class ParamSample(Sample):
    """PARAM_VALUE decoded: integers come back as ``int`` (PX4 byte-encodes them in a float)."""

    name: str
    value: int | float
    index: int
    count: int


@dataclass(frozen=True, slots=True, kw_only=True)
class CommandAckSample(Sample):
    command: int
    result: int
    """MAV_RESULT (0 accepted, 3 unsupported...)."""
    target_system: int = 0
    target_component: int = 0
    """Whom it answers (MAVLink 2; 0: not said): a GCS on the same link sees its acks too."""

    def answers(self, system: int, component: int) -> bool:
        """Whether it answers that client (or says nobody in particular)."""
        return self.target_system in (0, system) and self.target_component in (0, component)


@dataclass(frozen=True, slots=True, kw_only=True)
class LinkStateSample(Sample):
    """The reader's view of the link: up on the first HEARTBEAT, down after a silence."""

    connected: bool
    reason: str


@dataclass(frozen=True, slots=True, kw_only=True)
class TelemetrySnapshot:
    """Everything known about the vehicle at one instant (None = not received yet)."""

    connected: bool = False
    t_heartbeat: float | None = None
    autopilot: str | None = None
    vehicle_type: int | None = None
    mode: str | None = None
    armed: bool | None = None
    system_status: int | None = None
    battery_v: float | None = None
    current_a: float | None = None
    battery_remaining: float | None = None
    t_battery: float | None = None
    lat_deg: float | None = None
    lon_deg: float | None = None
    alt_amsl_m: float | None = None
    alt_rel_m: float | None = None
    heading_deg: float | None = None
    t_position: float | None = None
    roll_rad: float | None = None
    pitch_rad: float | None = None
    yaw_rad: float | None = None
    t_attitude: float | None = None
    gps_fix_type: int | None = None
    satellites: int | None = None
    t_gps: float | None = None
    estimator_position_ok: bool | None = None
    """None while no estimator report came on this connection (a stack that sends none is
    judged by GPS alone once :data:`ESTIMATOR_GRACE_S` has passed)."""
    t_estimator: float | None = None
    t_link_up: float | None = None
    """When the current connection's first HEARTBEAT came."""
    autopilot_unix_time_s: float | None = None
    last_statustext: str | None = None
    params: Mapping[str, int | float] = field(default_factory=dict)
    samples: int = 0
    reconnects: int = 0

    @property
    def has_pose(self) -> bool:
        return self.position_problem is None and self.roll_rad is not None

    @property
    def position_problem(self) -> str | None:
        """Why the position must not be used (None: a 3-D fix, an estimator with an origin,
        and not 0/0). ArduPilot reports 0/0 until its EKF has an origin; a position without
        a fix is a guess the operator must never see as a place."""
        if self.lat_deg is None or self.lon_deg is None:
            return "no position received"
        if self.gps_fix_type is None:
            return "no GPS report received"
        if self.gps_fix_type < GPS_FIX_3D:
            return f"no 3-D GPS fix (fix_type {self.gps_fix_type})"
        if self.estimator_position_ok is False:
            return "the estimator has no absolute position (no origin yet)"
        if self.estimator_position_ok is None and self.t_link_up is not None \
                and self.t_gps is not None and self.t_gps - self.t_link_up < ESTIMATOR_GRACE_S:
            return "waiting for the estimator's first report"
        if abs(self.lat_deg) < NULL_ISLAND_DEG and abs(self.lon_deg) < NULL_ISLAND_DEG:
            return "position is 0/0 (no origin)"
        if not (abs(self.lat_deg) <= 90.0 and abs(self.lon_deg) <= 180.0):
            # GLOBAL_POSITION_INT's int32 holds 214.7 deg: a broken or hostile autopilot's
            # "position" the station drew as a place (and took as its map's origin)
            return f"position {self.lat_deg:.7g}/{self.lon_deg:.7g} is not on Earth"
        return None

    def geotag(self, at: float | None = None) -> dict[str, Any]:
        """Position and attitude for a message's ``data`` (only the fields that are known).

        Without a valid position (:attr:`position_problem`) the tag has no coordinates and
        says ``position: "none"``. ``at`` (the capture time) adds ``pose_age_s``, how old
        the position is then.
        """
        if self.position_problem is not None:
            names: tuple[str, ...] = ("roll_rad", "pitch_rad", "yaw_rad", "heading_deg")
        else:
            names = ("lat_deg", "lon_deg", "alt_rel_m", "alt_amsl_m", "roll_rad",
                     "pitch_rad", "yaw_rad", "heading_deg")
        tag: dict[str, Any] = {n: v for n in names
                               if (v := getattr(self, n)) is not None and math.isfinite(v)}
        if self.position_problem is not None:
            tag["position"] = "none"
        elif at is not None and self.t_position is not None:
            tag["pose_age_s"] = round(max(0.0, at - self.t_position), 3)
        return tag


SampleListener = Callable[[Sample], None]


class TelemetryState:
    """The loop-side telemetry state. Not thread-safe by design: only the loop thread calls it."""

    def __init__(self, *, statustext_history: int = 50) -> None:
        self._snap = TelemetrySnapshot()
        self._fields: dict[str, object] = {}
        self._params: dict[str, int | float] = {}
        self.statustexts: deque[StatusTextSample] = deque(maxlen=statustext_history)
        self.acks: deque[CommandAckSample] = deque(maxlen=50)
        self._listeners: list[SampleListener] = []
        self._samples = 0
        self._reconnects = 0
        self._connected = False
        self._ever_connected = False

    def add_listener(self, listener: SampleListener) -> None:
        """Call ``listener(sample)`` after each applied sample (on the loop thread)."""
        self._listeners.append(listener)

    def apply(self, sample: Sample) -> None:
        """Fold one sample into the state (scheduled by the MAVLink thread)."""
        self._samples += 1
        f = self._fields
        match sample:
            case HeartbeatSample():
                f.update(t_heartbeat=sample.t, autopilot=sample.autopilot,
                         vehicle_type=sample.vehicle_type, mode=sample.mode,
                         armed=sample.armed, system_status=sample.system_status)
            case BatterySample():
                f.update(t_battery=sample.t)
                for name in ("battery_v", "current_a", "battery_remaining"):
                    value = getattr(sample, name)
                    if value is not None:
                        f[name] = value
            case PositionSample():
                f.update(t_position=sample.t, lat_deg=sample.lat_deg, lon_deg=sample.lon_deg,
                         alt_amsl_m=sample.alt_amsl_m, alt_rel_m=sample.alt_rel_m,
                         heading_deg=sample.heading_deg)
            case AttitudeSample():
                f.update(t_attitude=sample.t, roll_rad=sample.roll_rad,
                         pitch_rad=sample.pitch_rad, yaw_rad=sample.yaw_rad)
            case GpsSample():
                f.update(gps_fix_type=sample.fix_type, satellites=sample.satellites,
                         t_gps=sample.t)
            case EstimatorSample():
                f.update(estimator_position_ok=sample.position_ok, t_estimator=sample.t)
            case SystemTimeSample():
                f.update(autopilot_unix_time_s=sample.unix_time_s)
            case StatusTextSample():
                self.statustexts.append(sample)
                f.update(last_statustext=sample.text)
            case ParamSample():
                self._params[sample.name] = sample.value
            case CommandAckSample():
                self.acks.append(sample)
            case LinkStateSample():
                if sample.connected and not self._connected:
                    if self._ever_connected:
                        self._reconnects += 1
                    self._ever_connected = True
                    # a rebooted autopilot has no fix and no origin: the last connection's
                    # say nothing about this one's (their position stays, as the last known)
                    f.update(t_link_up=sample.t, gps_fix_type=None, satellites=None,
                             t_gps=None, estimator_position_ok=None, t_estimator=None)
                self._connected = sample.connected
        self._snap = TelemetrySnapshot(
            connected=self._connected,
            params=MappingProxyType(dict(self._params)),
            samples=self._samples,
            reconnects=self._reconnects,
            **f,  # type: ignore[arg-type]
        )
        for listener in self._listeners:
            listener(sample)

    def snapshot(self) -> TelemetrySnapshot:
        """An immutable copy of the current state, cheap to hand to other threads."""
        return self._snap
