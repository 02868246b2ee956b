"""The MAVLink side of one simulated vehicle, sans-I/O (aioquic-shaped).

Inputs: ``receive_datagram(data, addr, now)`` and ``handle_timer(now)``; outputs:
``datagrams_to_send() -> list[bytes]`` and ``get_timer() -> float`` (a deadline).
``now`` is the vehicle's own clock: simulated seconds since boot. pymavlink's generated
``MAVLink`` class is used only as a codec (``pack``/``parse_buffer``); the dialect module is
imported directly, so no pymavlink global state is touched.

Microservices: heartbeat and message streams (SET_MESSAGE_INTERVAL, REQUEST_DATA_STREAM,
REQUEST_MESSAGE), commands with COMMAND_ACK, parameters (list/read/set), missions
(upload/download/clear/set-current, MISSION_ITEM_REACHED, AUTO execution),
SET_POSITION_TARGET_LOCAL_NED/GLOBAL_INT, TIMESYNC. Bad input is counted in ``counters``.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sitl.geo import GeoPoint, enu_from_geo
from sitl.vehicle.autopilot import (
    ACCEPTED,
    DENIED,
    FAILED,
    UNSUPPORTED,
    CommandResult,
    CurrentItemChanged,
    FixAcquired,
    FlightController,
    GuidedTarget,
    HomeChanged,
    ItemReached,
    ModeChanged,
    StatusText,
)
from sitl.vehicle.flavour import PX4, Flavour, Mode, decode_param_value, encode_param_value
from sitl.vehicle.mission import (
    GLOBAL_FRAMES,
    RELATIVE_FRAMES,
    MissionItem,
    commanded_alt_rel_m,
    is_nav_command,
)
from sitl.vehicle.params import ParamTable
from sitl.vehicle.physics import Airframe
from sitl.vehicle.telemetry import (
    DEFAULT_INTERVALS_S,
    MSG_HEARTBEAT,
    PX4_EXTRA_INTERVALS_S,
    STREAM_GROUPS,
    Telemetry,
)
from sitl.vehicle.traffic import TrafficAwareness, TrafficList

__all__ = ["DEFAULT_FIRST_FIX_S", "DEFAULT_HOME", "VehicleConfig", "VehicleCore"]

DEFAULT_HOME = GeoPoint(lat_deg=47.397742, lon_deg=8.545594, alt_m=488.0)

# MAV_MISSION_RESULT
MISSION_ACCEPTED = 0
MISSION_NO_SPACE = 4
MISSION_INVALID_SEQUENCE = 13
MISSION_CANCELLED = 15
MAX_MISSION_ITEMS = 1000

DEFAULT_FIRST_FIX_S = 15.0
"""ArduCopter SITL reports an EKF origin 10-20 s after boot; PX4 SIH in a similar time."""

CONTROL_PERIOD_S = 0.1
TRAFFIC_PERIOD_S = 1.0
"""The traffic list is aged, checked for threats and streamed once a (wall) second."""
"""The core wakes at least this often (sim s) so mission events are never late by more."""


@dataclass(frozen=True, slots=True, kw_only=True)
class VehicleConfig:
    """Everything that makes one simulated vehicle; a launcher builds N of these."""

    system_id: int = 1
    flavour: Flavour = PX4
    home: GeoPoint = DEFAULT_HOME
    airframe: Airframe = field(default_factory=Airframe)
    params: Mapping[str, float] = field(default_factory=dict)
    """Parameter overrides, e.g. {"MIS_TAKEOFF_ALT": 10.0}."""
    mission: tuple[MissionItem, ...] = ()
    """Mission preloaded at boot (a flight pattern)."""
    physics_dt_s: float = 0.02
    protocol_timeout_s: float = 1.0
    """Retry period of mission-upload requests (wall seconds, see ``speedup``)."""
    speedup: float = 1.0
    """Simulated seconds per wall second. Stream rates and protocol timeouts are per *wall*
    second, as a real link carries them: a 10 Hz stream stays 10 Hz when the flight runs 20x
    faster (it then samples the flight every 2 simulated seconds)."""
    gps_sigma_h_m: float = 0.3
    gust_fraction: float = 0.2
    boot_unix_s: float = 1_700_000_000.0
    """Unix time at simulated t = 0 (SYSTEM_TIME = boot_unix_s + now)."""
    seed: int = 0
    first_fix_s: float = DEFAULT_FIRST_FIX_S
    """Simulated seconds from boot to a 3D fix and estimator origin. Before it, as on a real
    ArduCopter or PX4 just booted: GPS_RAW_INT fix_type 1 at 0/0, no home or origin, EKF flags
    without horizontal position, arming refused with the stack's STATUSTEXT (ArduPilot
    "Arm:"/"PreArm: ...", PX4 "Navigation error: ...") and on ArduPilot GLOBAL_POSITION_INT
    at 0/0 (PX4 sends none). 0 for tests that fly at once."""
    autostart: bool = False
    """Arm and start the preloaded mission as soon as the vehicle can arm (after the fix)."""

    def __post_init__(self) -> None:
        if not 1 <= self.system_id <= 255:
            raise ValueError(f"system_id must be in 1..255, got {self.system_id}")
        if not self.speedup > 0.0:
            raise ValueError(f"speedup must be > 0, got {self.speedup}")
        if not (math.isfinite(self.first_fix_s) and self.first_fix_s >= 0.0):
            raise ValueError(f"first_fix_s must be >= 0, got {self.first_fix_s}")


@dataclass(slots=True, kw_only=True)
class _Upload:
    mission_type: int
    count: int
    peer: tuple[int, int]
    items: list[MissionItem] = field(default_factory=list)
    deadline: float = 0.0
    retries: int = 0


class BadField(ValueError):
    """A field of a received message that is NaN, infinite or out of range."""


def _int(value: float, name: str) -> int:
    """An integer-valued command parameter; NaN/inf are bad input, not a crash."""
    if not math.isfinite(value) or abs(value) > 2**31:
        raise BadField(f"{name} must be a finite integer, got {value}")
    return int(value)


def _finite(values: tuple[float, ...], name: str) -> tuple[float, ...]:
    if not all(math.isfinite(v) for v in values):
        raise BadField(f"{name} must be finite, got {values}")
    return values


def _lat_lon(lat_deg: float, lon_deg: float) -> tuple[float, float]:
    if not (math.isfinite(lat_deg) and -90.0 <= lat_deg <= 90.0 and math.isfinite(lon_deg)
            and -180.0 <= lon_deg <= 180.0):
        raise BadField(f"latitude/longitude out of range: {lat_deg}, {lon_deg}")
    return lat_deg, lon_deg


def _text(value: Any) -> str:
    if isinstance(value, bytes):
        value = value.decode("utf-8", "replace")
    return str(value).split("\x00", 1)[0]


def _item_error(msg: Any, scale: float) -> int | None:
    """MAV_MISSION_RESULT for an item no vehicle could fly, or None when it is acceptable."""
    if (msg.frame in GLOBAL_FRAMES | RELATIVE_FRAMES and is_nav_command(msg.command)
            and not (msg.x == 0 and msg.y == 0)):
        lat, lon = msg.x * scale, msg.y * scale
        if not (math.isfinite(lat) and -90.0 <= lat <= 90.0):
            return 10  # MAV_MISSION_INVALID_PARAM5_X
        if not (math.isfinite(lon) and -180.0 <= lon <= 180.0):
            return 11  # MAV_MISSION_INVALID_PARAM6_Y
    if is_nav_command(msg.command) and msg.command != 20 and not math.isfinite(msg.z):
        return 12  # MAV_MISSION_INVALID_PARAM7
    return None


class VehicleCore:
    """One simulated vehicle's MAVLink endpoint (see module docstring)."""

    def __init__(self, config: VehicleConfig, *, now: float = 0.0) -> None:
        self.config = config
        self.flavour = config.flavour
        sysid = config.system_id
        overrides = dict(config.params)
        id_param = "MAV_SYS_ID" if "MAV_SYS_ID" in {p.name for p in self.flavour.params} else (
            "SYSID_THISMAV")
        overrides.setdefault(id_param, sysid)
        self.params = ParamTable(self.flavour.params, overrides)
        self.fc = FlightController(flavour=self.flavour, params=self.params, home=config.home,
                                   airframe=config.airframe, dt_s=config.physics_dt_s,
                                   gust_fraction=config.gust_fraction,
                                   first_fix_s=config.first_fix_s)
        self.fc.advance_to(now)
        self._tx = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=1)
        self._rx = self._new_parser()
        self._out: list[bytes] = []
        self.counters: Counter[str] = Counter()
        self._intervals: dict[int, float] = (
            {**DEFAULT_INTERVALS_S, **PX4_EXTRA_INTERVALS_S} if self.flavour.streams_unrequested
            else {MSG_HEARTBEAT: 1.0}
        )
        self._next_due: dict[int, float] = dict.fromkeys(self._intervals, now)
        self._stored: dict[int, list[MissionItem]] = {0: list(config.mission), 1: [], 2: []}
        self.telemetry = Telemetry(
            self.fc, flavour=self.flavour, system_id=sysid, home=config.home,
            boot_unix_s=config.boot_unix_s, gps_sigma_h_m=config.gps_sigma_h_m,
            rng=np.random.default_rng(config.seed), mission_total=lambda: len(self._stored[0]))
        self._builders = self.telemetry.builders
        self._handlers: dict[str, Callable[[Any, float], None]] = {
            "HEARTBEAT": self._on_heartbeat,
            "COMMAND_LONG": self._on_command_long,
            "COMMAND_INT": self._on_command_int,
            "SET_MODE": self._on_set_mode,
            "PARAM_REQUEST_LIST": self._on_param_request_list,
            "PARAM_REQUEST_READ": self._on_param_request_read,
            "PARAM_SET": self._on_param_set,
            "MISSION_COUNT": self._on_mission_count,
            "MISSION_ITEM_INT": self._on_mission_item,
            "MISSION_ITEM": self._on_mission_item,
            "MISSION_REQUEST_LIST": self._on_mission_request_list,
            "MISSION_REQUEST_INT": self._on_mission_request,
            "MISSION_REQUEST": self._on_mission_request,
            "MISSION_ACK": self._on_mission_ack,
            "MISSION_CLEAR_ALL": self._on_mission_clear_all,
            "MISSION_SET_CURRENT": self._on_mission_set_current,
            "REQUEST_DATA_STREAM": self._on_request_data_stream,
            "SET_POSITION_TARGET_LOCAL_NED": self._on_position_target_local,
            "SET_POSITION_TARGET_GLOBAL_INT": self._on_position_target_global,
            "TIMESYNC": self._on_timesync,
            "PING": self._on_ping,
            "ADSB_VEHICLE": self._on_adsb_vehicle,  # sitl.vehicle.traffic
        }
        self.awareness = TrafficAwareness(flavour=self.flavour.name, params=self.params,
                                          fc=self.fc, home=config.home)
        self._next_traffic = now
        if config.mission:
            self.fc.set_mission(list(config.mission))
        self._upload: _Upload | None = None
        self._last_control = now
        self.gcs_heard = False
        self._autostart_pending = config.autostart and bool(config.mission)
        self._drain_events(now)
        self._try_autostart()

    def _new_parser(self) -> Any:
        parser = mavlink.MAVLink(None, srcSystem=self.config.system_id, srcComponent=1)
        parser.robust_parsing = True
        return parser

    # ------------------------------------------------------------------ public sans-I/O API

    @property
    def system_id(self) -> int:
        return self.config.system_id

    def datagrams_to_send(self) -> list[bytes]:
        """Pop the packed MAVLink frames produced so far (one frame per datagram)."""
        out, self._out = self._out, []
        return out

    def get_timer(self) -> float:
        """The next deadline (vehicle seconds) at which ``handle_timer`` must run."""
        deadline = min(self._last_control + CONTROL_PERIOD_S, self._next_traffic)
        if self._next_due:
            deadline = min(deadline, min(self._next_due.values()))
        if self._upload is not None:
            deadline = min(deadline, self._upload.deadline)
        return deadline

    def handle_timer(self, now: float) -> None:
        self._advance(now)
        if now >= self._next_traffic:  # age the list, stream it as the stacks do
            self._next_traffic = now + TRAFFIC_PERIOD_S * self.config.speedup
            self._traffic_tick(now)
        for msg_id, due in list(self._next_due.items()):
            if due <= now + 1e-9:
                interval = self._intervals[msg_id] * self.config.speedup
                built = self._builders[msg_id](now)
                if built is not None:  # None: not available yet (no home before the fix)
                    self._send(built)
                # Keep the cadence, but never queue a backlog after a stall.
                self._next_due[msg_id] = max(due + interval, now + 0.5 * interval)
        up = self._upload
        if up is not None and now >= up.deadline:
            up.retries += 1
            if up.retries > 5:
                self.counters["mission_upload_timeout"] += 1
                self._send(mavlink.MAVLink_mission_ack_message(
                    up.peer[0], up.peer[1], MISSION_CANCELLED, up.mission_type))
                self._upload = None
            else:
                self._request_item(up, now)

    def receive_datagram(self, data: bytes, addr: object, now: float) -> None:
        """Decode and act on one datagram; bad bytes are counted, never raised."""
        self._advance(now)
        try:
            msgs = self._rx.parse_buffer(data) or []
        except mavlink.MAVError:
            self.counters["malformed"] += 1
            self._rx = self._new_parser()
            return
        for msg in msgs:
            kind = msg.get_type()
            if kind == "BAD_DATA":
                self.counters["bad_data"] += 1
                continue
            handler = self._handlers.get(kind)
            if handler is None:
                # Known but unhandled types by name; unknown ids in one bucket (bounded keys).
                key = "unknown_message" if kind.startswith("UNKNOWN") else kind.lower()
                self.counters["ignored_" + key] += 1
                continue
            target = getattr(msg, "target_system", 0)
            if target not in (0, self.system_id):
                self.counters["not_for_us"] += 1
                continue
            try:
                handler(msg, now)
            except BadField as exc:
                # A well-formed frame with values no vehicle can act on (NaN, out of range).
                self.counters["invalid_" + kind.lower()] += 1
                self.statustext(4, f"Rejected {kind}: {exc}"[:50])
        self._drain_events(now)

    # ----------------------------------------------------------------------------- helpers

    def _advance(self, now: float) -> None:
        self.fc.advance_to(now)
        self._last_control = now
        self._drain_events(now)
        self._try_autostart()

    def _try_autostart(self) -> None:
        """``autostart``: arm and fly the preloaded mission once pre-arm checks pass."""
        if not self._autostart_pending or not self.fc.has_fix:
            return
        self._autostart_pending = False
        if self.fc.arm().ok:
            self.fc.set_mode(Mode.MISSION)
        self._drain_events(self.fc.state.t_s)

    def _send(self, msg: Any) -> None:
        self._out.append(msg.pack(self._tx))
        self._tx.seq = (self._tx.seq + 1) % 256

    def statustext(self, severity: int, text: str) -> None:
        self._send(mavlink.MAVLink_statustext_message(severity, text[:50].encode(), 0, 0))

    def _drain_events(self, now: float) -> None:
        while (ev := self.fc.next_event()) is not None:
            if isinstance(ev, StatusText):
                self.statustext(ev.severity, ev.text)
            elif isinstance(ev, ItemReached):
                self._send(mavlink.MAVLink_mission_item_reached_message(ev.seq))
            elif isinstance(ev, CurrentItemChanged):
                self._send(self.telemetry.mission_current(now))
            elif isinstance(ev, ModeChanged):
                self._send(self.telemetry.heartbeat(now))
            elif isinstance(ev, FixAcquired):
                # Both stacks announce home and origin to every link when they are set.
                if self.flavour.name == "ardupilot":
                    self.statustext(6, "EKF3 IMU0 is using GPS")
                    self.statustext(6, "EKF3 IMU0 origin set")
                self._send(self.telemetry.gps_global_origin(now))
                self._send(self.telemetry.home_position(now))
            elif isinstance(ev, HomeChanged):
                self._send(self.telemetry.home_position(now))

    def _geo_to_ned(self, lat_deg: float, lon_deg: float, alt_rel_m: float
                    ) -> tuple[float, float, float]:
        home = self.config.home
        local = enu_from_geo(GeoPoint(lat_deg=lat_deg, lon_deg=lon_deg, alt_m=home.alt_m), home)
        return (local.north_m, local.east_m, -alt_rel_m)

    # ---------------------------------------------------------------------------- streams

    def set_interval(self, msg_id: int, interval_s: float | None, now: float) -> bool:
        """Stream ``msg_id`` every ``interval_s`` wall seconds (None stops it); False if we
        lack it."""
        if msg_id not in self._builders:
            return False
        if interval_s is None:
            self._intervals.pop(msg_id, None)
            self._next_due.pop(msg_id, None)
        else:
            self._intervals[msg_id] = interval_s
            self._next_due[msg_id] = now
        return True

    # --------------------------------------------------------------------------- handlers

    def _on_heartbeat(self, msg: Any, now: float) -> None:
        self.gcs_heard = True

    def _ack(self, msg: Any, command: int, res: CommandResult) -> None:
        if res.text:
            self.statustext(4 if not res.ok else 6, res.text)
        self._send(mavlink.MAVLink_command_ack_message(
            command, res.result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()))

    def _on_command_long(self, msg: Any, now: float) -> None:
        params = [msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6,
                  msg.param7]
        self._command(msg, msg.command, params, frame=None, now=now)

    def _on_command_int(self, msg: Any, now: float) -> None:
        params = [msg.param1, msg.param2, msg.param3, msg.param4, msg.x / 1e7, msg.y / 1e7,
                  msg.z]
        self._command(msg, msg.command, params, frame=msg.frame, now=now)

    def _command(self, msg: Any, command: int, p: list[float], *, frame: int | None,
                 now: float) -> None:
        fc = self.fc
        follow_up: Any = None
        res: CommandResult
        if command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            force = abs(p[1] - 21196.0) < 0.5
            res = fc.arm(force=force) if p[0] >= 0.5 else fc.disarm(force=force)
        elif command == mavlink.MAV_CMD_NAV_TAKEOFF:
            alt: float | None = p[6] if math.isfinite(p[6]) else None
            if alt is not None and self.flavour.takeoff_param7_amsl:
                alt = commanded_alt_rel_m(frame, alt, self.config.home)
            res = fc.takeoff(alt)
        elif command == mavlink.MAV_CMD_NAV_LAND:
            res = fc.land()
        elif command == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            res = fc.return_to_launch()
        elif command == mavlink.MAV_CMD_DO_SET_MODE:
            res = self._set_mode_from(_int(p[0], "base_mode"), _int(p[1], "custom_mode"),
                                      _int(p[2], "custom_sub_mode") if math.isfinite(p[2])
                                      else 0)
        elif command == mavlink.MAV_CMD_MISSION_START:
            res = fc.start_mission(_int(p[0], "first_item") if p[0] > 0 else None)
        elif command == mavlink.MAV_CMD_DO_SET_MISSION_CURRENT:
            res = fc.set_current_item(_int(p[0], "seq"))
        elif command == mavlink.MAV_CMD_DO_CHANGE_SPEED:
            res = fc.set_speed(p[1])
        elif command == mavlink.MAV_CMD_DO_REPOSITION:
            here = fc.state.position_ned_m
            if math.isfinite(p[4]) and math.isfinite(p[5]):
                _lat_lon(p[4], p[5])
                alt_rel = -here[2]
                if math.isfinite(p[6]):
                    alt_rel = commanded_alt_rel_m(frame, p[6], self.config.home)
                target = self._geo_to_ned(p[4], p[5], alt_rel)
            else:
                target = here
            res = fc.reposition(target)
        elif command == mavlink.MAV_CMD_DO_SET_ROI_LOCATION:
            lat, lon = _lat_lon(p[4], p[5])
            alt_rel = 0.0
            if math.isfinite(p[6]):
                alt_rel = commanded_alt_rel_m(frame, p[6], self.config.home)
            res = fc.set_roi(self._geo_to_ned(lat, lon, alt_rel))
        elif command == mavlink.MAV_CMD_DO_SET_ROI_NONE:
            res = fc.set_roi(None)
        elif command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            msg_id, interval_us = _int(p[0], "message_id"), _int(p[1], "interval_us")
            if interval_us < 0:
                interval: float | None = None
            elif interval_us == 0:
                interval = {**DEFAULT_INTERVALS_S, **PX4_EXTRA_INTERVALS_S}.get(msg_id, 1.0)
            else:
                interval = interval_us / 1e6
            ok = self.set_interval(msg_id, interval, now)
            res = CommandResult(result=ACCEPTED if ok else UNSUPPORTED)
        elif command == mavlink.MAV_CMD_GET_MESSAGE_INTERVAL:
            msg_id = _int(p[0], "message_id")
            if msg_id in self._builders:
                iv = self._intervals.get(msg_id)
                follow_up = mavlink.MAVLink_message_interval_message(
                    msg_id, -1 if iv is None else int(iv * 1e6))
                res = CommandResult(result=ACCEPTED)
            else:
                res = CommandResult(result=UNSUPPORTED)
        elif command == mavlink.MAV_CMD_REQUEST_MESSAGE:
            builder = self._builders.get(_int(p[0], "message_id"))
            follow_up = builder(now) if builder else None
            res = CommandResult(result=UNSUPPORTED if builder is None else
                                FAILED if follow_up is None else ACCEPTED)
        elif command == mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            res = CommandResult(result=ACCEPTED)
            follow_up = self.telemetry.autopilot_version(now)
        elif command == mavlink.MAV_CMD_GET_HOME_POSITION:
            follow_up = self.telemetry.home_position(now)
            res = CommandResult(result=FAILED if follow_up is None else ACCEPTED)
        elif command in self.flavour.accepted_commands:
            res = self._peripheral_command(command, p, frame)
        else:
            self.counters["unsupported_command"] += 1
            res = CommandResult(result=UNSUPPORTED)
        self._ack(msg, command, res)
        if follow_up is not None:
            self._send(follow_up)

    def _peripheral_command(self, command: int, p: list[float], frame: int | None
                            ) -> CommandResult:
        """Servo, relay, yaw, home, camera and fence commands (``Flavour.accepted_commands``)."""
        fc = self.fc
        if command == mavlink.MAV_CMD_DO_SET_SERVO:
            return fc.set_servo(_int(p[0], "instance"), _int(p[1], "pwm"))
        if command == mavlink.MAV_CMD_DO_SET_RELAY:
            return fc.set_relay(_int(p[0], "instance"), p[1] >= 0.5)
        if command == mavlink.MAV_CMD_CONDITION_YAW:
            if not math.isfinite(p[3]) or p[3] not in (0.0, 1.0):
                return CommandResult(result=FAILED)
            return fc.condition_yaw(p[0], p[2], relative=p[3] == 1.0)
        if command == mavlink.MAV_CMD_DO_SET_HOME:
            # param1 = 1, or lat/lon both 0: here (as ArduPilot reads it).
            if p[0] >= 0.5 or (p[4] == 0.0 and p[5] == 0.0):
                return fc.set_home(None)
            lat, lon = _lat_lon(p[4], p[5])
            alt_amsl = p[6] if math.isfinite(p[6]) else self.config.home.alt_m
            return fc.set_home(self._geo_to_ned(lat, lon, alt_amsl - self.config.home.alt_m))
        if command == mavlink.MAV_CMD_DO_DIGICAM_CONTROL:
            return fc.trigger_camera()
        if command == mavlink.MAV_CMD_DO_FENCE_ENABLE:
            action = _int(p[0], "enable")
            if action not in (0, 1, 2):
                return CommandResult(result=FAILED)
            self.params.set("FENCE_ENABLE", 1.0 if action == 1 else 0.0)
            return CommandResult(result=ACCEPTED)
        return CommandResult(result=UNSUPPORTED)

    def _set_mode_from(self, base_mode: int, custom: int, sub: int) -> CommandResult:
        if not base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return CommandResult(result=UNSUPPORTED, text="Mode: only custom modes")
        if self.flavour.name == "px4":
            custom = (custom << 16) | (sub << 24)
        mode = self.flavour.mode_from_custom(custom)
        if mode is None:
            return CommandResult(result=DENIED if self.flavour.name == "px4" else FAILED,
                                 text=f"Mode: unknown custom mode {custom}")
        return self.fc.set_mode(mode)

    def _on_set_mode(self, msg: Any, now: float) -> None:
        if self.flavour.name == "px4":
            mode = self.flavour.mode_from_custom(msg.custom_mode)
            res = self.fc.set_mode(mode) if mode else CommandResult(result=DENIED)
        else:
            res = self._set_mode_from(msg.base_mode, msg.custom_mode, 0)
        # SET_MODE is acknowledged as DO_SET_MODE by both autopilots.
        self._ack(msg, mavlink.MAV_CMD_DO_SET_MODE, res)

    # ---------------------------------------------------------------------- parameters

    def _param_value(self, name: str) -> Any:
        spec = self.params.spec(name)
        raw = encode_param_value(self.params.get(name), spec.param_type,
                                 bytewise=self.flavour.param_bytewise)
        return mavlink.MAVLink_param_value_message(
            name.encode(), raw, spec.param_type, len(self.params), self.params.index(name))

    def _on_param_request_list(self, msg: Any, now: float) -> None:
        for name in self.params.names:
            self._send(self._param_value(name))

    def _on_param_request_read(self, msg: Any, now: float) -> None:
        name = self.params.name_at(msg.param_index) if msg.param_index >= 0 else _text(
            msg.param_id)
        if name is None or name not in self.params:
            self.counters["unknown_param"] += 1
            if self.flavour.unknown_param_read_text and msg.param_index >= 0:
                self.statustext(6, f"[pm] unknown param ID: {msg.param_index}")
            return
        self._send(self._param_value(name))

    def _on_param_set(self, msg: Any, now: float) -> None:
        name = _text(msg.param_id)
        if name not in self.params:
            self.counters["unknown_param"] += 1
            if self.flavour.unknown_param_read_text:
                self.statustext(6, f"[pm] unknown param: {name}")
            return
        spec = self.params.spec(name)
        value = decode_param_value(msg.param_value, spec.param_type,
                                   bytewise=self.flavour.param_bytewise)
        if not math.isfinite(value):
            self.counters["bad_param_value"] += 1
            return
        self.params.set(name, value)
        self.fc.on_params_changed()
        self._send(self._param_value(name))

    # ------------------------------------------------------------------------- missions

    def _on_mission_count(self, msg: Any, now: float) -> None:
        mtype = getattr(msg, "mission_type", 0)
        peer = (msg.get_srcSystem(), msg.get_srcComponent())
        if mtype not in self._stored:
            self._send(mavlink.MAVLink_mission_ack_message(*peer, 3, mtype))
            return
        if msg.count > MAX_MISSION_ITEMS:
            self._send(mavlink.MAVLink_mission_ack_message(*peer, MISSION_NO_SPACE, mtype))
            return
        if msg.count == 0:
            self._upload = None
            self._store(mtype, [])
            self._send(mavlink.MAVLink_mission_ack_message(*peer, MISSION_ACCEPTED, mtype))
            return
        self._upload = _Upload(mission_type=mtype, count=msg.count, peer=peer)
        self._request_item(self._upload, now)

    def _request_item(self, up: _Upload, now: float) -> None:
        up.deadline = now + self.config.protocol_timeout_s * self.config.speedup
        self._send(mavlink.MAVLink_mission_request_int_message(
            up.peer[0], up.peer[1], len(up.items), up.mission_type))

    def _on_mission_item(self, msg: Any, now: float) -> None:
        up = self._upload
        mtype = getattr(msg, "mission_type", 0)
        if up is None or mtype != up.mission_type:
            self.counters["mission_item_unexpected"] += 1
            return
        if msg.seq != len(up.items):
            self.counters["mission_item_out_of_sequence"] += 1
            self._request_item(up, now)
            return
        is_int = msg.get_type() == "MISSION_ITEM_INT"
        scale = 1e-7 if is_int else 1.0
        item_error = _item_error(msg, scale)
        if item_error is not None:
            self.counters["mission_item_invalid"] += 1
            self._upload = None
            self._send(mavlink.MAVLink_mission_ack_message(*up.peer, item_error, mtype))
            return
        up.items.append(MissionItem(
            seq=msg.seq, frame=msg.frame, command=msg.command, current=msg.current,
            autocontinue=msg.autocontinue, param1=msg.param1, param2=msg.param2,
            param3=msg.param3, param4=msg.param4, lat_deg=msg.x * scale, lon_deg=msg.y * scale,
            z_m=msg.z, mission_type=mtype))
        up.retries = 0
        if len(up.items) < up.count:
            self._request_item(up, now)
            return
        self._upload = None
        self._store(mtype, up.items)
        self._send(mavlink.MAVLink_mission_ack_message(*up.peer, MISSION_ACCEPTED, mtype))

    def _store(self, mission_type: int, items: list[MissionItem]) -> None:
        self._stored[mission_type] = list(items)
        if mission_type == 0:
            self.fc.set_mission(list(items))

    def _download_item(self, mission_type: int, seq: int) -> MissionItem | None:
        items = self._stored.get(mission_type, [])
        if not 0 <= seq < len(items):
            return None
        if mission_type == 0 and seq == 0 and self.flavour.mission_item0_is_home:
            home = self.config.home
            return MissionItem(seq=0, frame=0, command=16, lat_deg=home.lat_deg,
                               lon_deg=home.lon_deg, z_m=home.alt_m)
        return items[seq]

    def _on_mission_request_list(self, msg: Any, now: float) -> None:
        mtype = getattr(msg, "mission_type", 0)
        count = len(self._stored.get(mtype, []))
        self._send(mavlink.MAVLink_mission_count_message(
            msg.get_srcSystem(), msg.get_srcComponent(), count, mtype))

    def _on_mission_request(self, msg: Any, now: float) -> None:
        mtype = getattr(msg, "mission_type", 0)
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        item = self._download_item(mtype, msg.seq)
        if item is None:
            self._send(mavlink.MAVLink_mission_ack_message(*src, MISSION_INVALID_SEQUENCE,
                                                           mtype))
            return
        current = int(item.seq == self.fc.mission_current and mtype == 0)
        if msg.get_type() == "MISSION_REQUEST_INT":
            self._send(mavlink.MAVLink_mission_item_int_message(
                *src, item.seq, item.frame, item.command, current, item.autocontinue,
                item.param1, item.param2, item.param3, item.param4,
                round(item.lat_deg * 1e7), round(item.lon_deg * 1e7), item.z_m,
                mtype))
        else:
            self._send(mavlink.MAVLink_mission_item_message(
                *src, item.seq, item.frame, item.command, current, item.autocontinue,
                item.param1, item.param2, item.param3, item.param4, item.lat_deg,
                item.lon_deg, item.z_m, mtype))

    def _on_mission_ack(self, msg: Any, now: float) -> None:
        if self._upload is not None and msg.type != MISSION_ACCEPTED:
            self.counters["mission_upload_cancelled"] += 1
            self._upload = None

    def _on_mission_clear_all(self, msg: Any, now: float) -> None:
        mtype = getattr(msg, "mission_type", 0)
        self._upload = None
        if mtype == 255:  # MAV_MISSION_TYPE_ALL
            for key in self._stored:
                self._store(key, [])
        elif mtype in self._stored:
            self._store(mtype, [])
        self._send(mavlink.MAVLink_mission_ack_message(
            msg.get_srcSystem(), msg.get_srcComponent(), MISSION_ACCEPTED, mtype))

    def _on_mission_set_current(self, msg: Any, now: float) -> None:
        res = self.fc.set_current_item(msg.seq)
        if not res.ok:
            self.statustext(4, res.text or "Mission: bad item")
        self._send(self.telemetry.mission_current(now))

    # ------------------------------------------------------------------ streams, guided

    def _on_request_data_stream(self, msg: Any, now: float) -> None:
        if self.flavour.name != "ardupilot":
            self.counters["ignored_request_data_stream"] += 1
            return
        groups = list(STREAM_GROUPS) if msg.req_stream_id == 0 else [msg.req_stream_id]
        for group in groups:
            for msg_id in STREAM_GROUPS.get(group, ()):
                on = msg.start_stop and msg.req_message_rate > 0
                self.set_interval(msg_id, 1.0 / msg.req_message_rate if on else None, now)

    def _guided_from_mask(self, mask: int, pos: tuple[float, float, float] | None,
                          vel: tuple[float, float, float], yaw: float, now: float) -> None:
        use_pos = pos is not None and not mask & 0b111
        use_vel = not mask & 0b111000
        if use_pos and pos is not None:
            _finite(pos, "position")
        if use_vel:
            _finite(vel, "velocity")
        target = GuidedTarget(
            position_ned_m=pos if use_pos else None,
            velocity_ned_m_s=vel if use_vel and not use_pos else None,
            yaw_rad=None if mask & 1024 or not math.isfinite(yaw) else yaw,
            t_s=now,
        )
        if target.position_ned_m is None and target.velocity_ned_m_s is None:
            self.counters["position_target_ignored"] += 1
            return
        self.fc.set_guided_target(target)

    def _on_position_target_local(self, msg: Any, now: float) -> None:
        frame = msg.coordinate_frame
        st = self.fc.state
        pos = (msg.x, msg.y, msg.z)
        vel = (msg.vx, msg.vy, msg.vz)
        if frame in (mavlink.MAV_FRAME_BODY_NED, mavlink.MAV_FRAME_BODY_OFFSET_NED,
                     mavlink.MAV_FRAME_BODY_FRD):
            c, s = math.cos(st.yaw_rad), math.sin(st.yaw_rad)
            pos = (c * pos[0] - s * pos[1], s * pos[0] + c * pos[1], pos[2])
            vel = (c * vel[0] - s * vel[1], s * vel[0] + c * vel[1], vel[2])
        if frame in (mavlink.MAV_FRAME_LOCAL_OFFSET_NED, mavlink.MAV_FRAME_BODY_NED,
                     mavlink.MAV_FRAME_BODY_OFFSET_NED, mavlink.MAV_FRAME_BODY_FRD):
            here = st.position_ned_m
            pos = (here[0] + pos[0], here[1] + pos[1], here[2] + pos[2])
        self._guided_from_mask(msg.type_mask, pos, vel, msg.yaw, now)

    def _on_position_target_global(self, msg: Any, now: float) -> None:
        alt_rel = commanded_alt_rel_m(msg.coordinate_frame, msg.alt, self.config.home)
        pos = None
        if not msg.type_mask & 0b111:
            lat, lon = _lat_lon(msg.lat_int / 1e7, msg.lon_int / 1e7)
            pos = self._geo_to_ned(lat, lon, _finite((alt_rel,), "alt")[0])
        self._guided_from_mask(msg.type_mask, pos, (msg.vx, msg.vy, msg.vz), msg.yaw, now)

    # ------------------------------------------------------------ ADS-B traffic (peers)

    @property
    def traffic(self) -> TrafficList:
        """The vehicles this autopilot knows from ADSB_VEHICLE (sitl.vehicle.traffic)."""
        return self.awareness.traffic

    def _on_adsb_vehicle(self, msg: Any, now: float) -> None:
        self.awareness.on_adsb_vehicle(msg, now)
        self._flush_traffic_texts()

    def _flush_traffic_texts(self) -> None:
        for severity, text in self.awareness.texts:
            self.statustext(severity, text)
        self.awareness.texts.clear()

    def _traffic_tick(self, now: float) -> None:
        """Expire, check avoidance, and send the list to the clients as ADSB_VEHICLE with
        ``tslc`` = age (ArduPilot's SRn_ADSB stream, PX4's ADSB_VEHICLE stream)."""
        self.awareness.tick(now)
        self.awareness.check_avoidance(now)
        self._flush_traffic_texts()
        for vehicle in self.traffic.vehicles.values():
            r = vehicle.report
            self._send(mavlink.MAVLink_adsb_vehicle_message(
                r.icao_address, round(r.lat_deg * 1e7), round(r.lon_deg * 1e7), 1,
                round(r.alt_amsl_m * 1000), round(r.heading_deg * 100) % 36000,
                max(0, min(65535, round(r.hor_velocity_m_s * 100))),
                max(-32768, min(32767, round(r.ver_velocity_m_s * 100))),
                r.callsign.encode()[:8], r.emitter_type,
                max(0, min(255, int(vehicle.age(now)))), r.flags, r.squawk))

    def _on_ping(self, msg: Any, now: float) -> None:
        if msg.target_system == 0 and msg.target_component == 0:  # a request, not a reply
            self._send(mavlink.MAVLink_ping_message(
                msg.time_usec, msg.seq, msg.get_srcSystem(), msg.get_srcComponent()))

    def _on_timesync(self, msg: Any, now: float) -> None:
        if msg.tc1 == 0:
            self._send(mavlink.MAVLink_timesync_message(int(now * 1e9), msg.ts1))
