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
from collections.abc import Callable, Hashable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sitl.geo import GeoPoint, enu_from_geo
from sitl.vehicle.autopilot import FlightController
from sitl.vehicle.autopilot_events import (
    CurrentItemChanged,
    FixAcquired,
    HomeChanged,
    ItemReached,
    ModeChanged,
    StatusText,
)
from sitl.vehicle.commands import CommandHandlers
from sitl.vehicle.core_traffic import TrafficHandlers
from sitl.vehicle.fields import BadField
from sitl.vehicle.flavour import PX4, Flavour, Mode
from sitl.vehicle.links import DEFAULT_LINK, LinkStreams
from sitl.vehicle.mission import MissionItem
from sitl.vehicle.mission_protocol import MISSION_CANCELLED, MissionProtocol, _Upload
from sitl.vehicle.params import ParamTable
from sitl.vehicle.physics import Airframe
from sitl.vehicle.stream_tables import (
    DEFAULT_INTERVALS_S,
    MSG_HEARTBEAT,
    PX4_EXTRA_INTERVALS_S,
    STREAM_GROUPS,
)
from sitl.vehicle.telemetry import Telemetry
from sitl.vehicle.traffic import TrafficAwareness

__all__ = ["ARDUPILOT_REBOOT_S", "DEFAULT_FIRST_FIX_S", "DEFAULT_HOME", "VehicleConfig",
           "VehicleCore"]

DEFAULT_HOME = GeoPoint(lat_deg=47.397742, lon_deg=8.545594, alt_m=488.0)


DEFAULT_FIRST_FIX_S = 15.0
"""ArduCopter 4.5 SITL (measured): EKF origin 18.5 s, a usable EKF position 41.5 s after
start; kept shorter so demos fly sooner. PX4 SIH: not measured."""

ARDUPILOT_REBOOT_S = 2.1
"""ArduCopter 4.5 SITL, MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN's ACK to the next HEARTBEAT: 2.1 s
on TCP and on a UART (2026-12-04: 2.14 s), within a client's 3 s heartbeat timeout."""

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
    """Arm and start the preloaded mission as soon as the vehicle can arm (after the fix);
    at the first boot only (a rebooted autopilot waits on the ground)."""
    reboot_s: float = 4.0
    """Wall seconds a reboot (MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN) keeps the vehicle silent
    (``uav-sitl vehicle`` gives the ArduPilot flavour ``ARDUPILOT_REBOOT_S``)."""

    def __post_init__(self) -> None:
        if not 1 <= self.system_id <= 255:
            raise ValueError(f"system_id must be in 1..255, got {self.system_id}")
        if not self.speedup > 0.0:
            raise ValueError(f"speedup must be > 0, got {self.speedup}")
        if not (math.isfinite(self.first_fix_s) and self.first_fix_s >= 0.0):
            raise ValueError(f"first_fix_s must be >= 0, got {self.first_fix_s}")
        if not (math.isfinite(self.reboot_s) and self.reboot_s >= 0.0):
            raise ValueError(f"reboot_s must be >= 0, got {self.reboot_s}")


class VehicleCore(CommandHandlers, MissionProtocol, TrafficHandlers):
    """One simulated vehicle's MAVLink endpoint (see module docstring)."""

    def __init__(self, config: VehicleConfig, *, now: float = 0.0,
                 links: Iterable[Hashable] = (DEFAULT_LINK,)) -> None:
        self.config = config
        self._link_keys = tuple(links)
        """The flight controller's links (sitl.vehicle.links): streams are per link."""
        self._links: dict[Hashable, LinkStreams] = {}
        self._current: Hashable | None = None
        """The link whose message is being handled (replies go there); None: every link."""
        self.flavour = config.flavour
        sysid = config.system_id
        overrides = dict(config.params)
        id_param = "MAV_SYS_ID" if "MAV_SYS_ID" in {p.name for p in self.flavour.params} else (
            "SYSID_THISMAV")
        overrides.setdefault(id_param, sysid)
        self.params = ParamTable(self.flavour.params, overrides)
        self.counters: Counter[str] = Counter()
        self._stored: dict[int, list[MissionItem]] = {0: list(config.mission), 1: [], 2: []}
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
        self.boots = 0
        self._boot_at = 0.0
        """Caller time of the last boot: the vehicle's own clock (``now`` inside) counts from
        it, as an autopilot's time since boot does."""
        self.rebooting_until: float | None = None
        """Caller time the vehicle is back from a reboot (MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN);
        until then it is silent and deaf."""
        self._reboot_requested = False
        self._boot(now, autostart=config.autostart)

    def _boot(self, now: float, *, autostart: bool) -> None:
        """Everything a boot starts from scratch: the flight controller (no fix, no EKF
        origin, disarmed, at home), the message streams (their defaults), the MAVLink
        sequence and parser, the traffic list. Parameters and stored missions persist, as
        in an autopilot's EEPROM/flash."""
        config = self.config
        sysid = config.system_id
        self.fc = FlightController(flavour=self.flavour, params=self.params, home=config.home,
                                   airframe=config.airframe, dt_s=config.physics_dt_s,
                                   gust_fraction=config.gust_fraction,
                                   first_fix_s=config.first_fix_s)
        self.fc.advance_to(now)
        self._tx = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=1)
        self._rx = self._new_parser()
        defaults = ({**DEFAULT_INTERVALS_S, **PX4_EXTRA_INTERVALS_S}
                    if self.flavour.streams_unrequested else {MSG_HEARTBEAT: 1.0})
        self._links = {key: LinkStreams.fresh(defaults, now) for key in self._link_keys}
        self.telemetry = Telemetry(
            self.fc, flavour=self.flavour, system_id=sysid, home=config.home,
            boot_unix_s=config.boot_unix_s + self._boot_at, gps_sigma_h_m=config.gps_sigma_h_m,
            rng=np.random.default_rng(config.seed + self.boots),
            mission_total=lambda: len(self._stored[0]))
        self._builders = self.telemetry.builders
        self.awareness = TrafficAwareness(flavour=self.flavour.name, params=self.params,
                                          fc=self.fc, home=config.home)
        self._next_traffic = now
        if self._stored[0]:
            self.fc.set_mission(list(self._stored[0]))
        self._upload: _Upload | None = None
        self._last_control = now
        self.gcs_heard = False
        self._autostart_pending = autostart and bool(self._stored[0])
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

    def datagrams_to_send(self, link: Hashable = DEFAULT_LINK) -> list[bytes]:
        """Pop the packed MAVLink frames produced so far for ``link`` (one frame each)."""
        streams = self._links.get(link)
        if streams is None:
            return []
        out, streams.out = streams.out, []
        return out

    def forwards_to_send(self, link: Hashable = DEFAULT_LINK) -> list[tuple[object, bytes]]:
        """Pop (sender, frame) of clients' HEARTBEATs for ``link``'s clients: ArduPilot
        routes a component's broadcast messages to its other links, so a GCS sees the
        companion's HEARTBEAT (same system id, component 191; measured on ArduCopter 4.5
        SITL). ``sender`` is the client's address when it came on this link (not echoed to
        it), else None. A shell with one client drops them (at most 64 are kept)."""
        streams = self._links.get(link)
        if streams is None:
            return []
        out = list(streams.forwards)
        streams.forwards.clear()
        return out

    def get_timer(self) -> float:
        """The next deadline (caller seconds) at which ``handle_timer`` must run."""
        if self.rebooting_until is not None:
            return self.rebooting_until
        deadline = min(self._last_control + CONTROL_PERIOD_S, self._next_traffic)
        for streams in self._links.values():
            due = streams.next_deadline()
            if due is not None:
                deadline = min(deadline, due)
        if self._upload is not None:
            deadline = min(deadline, self._upload.deadline)
        return deadline + self._boot_at

    def handle_timer(self, now: float) -> None:
        if not self._running(now):
            return
        now -= self._boot_at
        self._advance(now)
        if now >= self._next_traffic:  # age the list, stream it as the stacks do
            self._next_traffic = now + TRAFFIC_PERIOD_S * self.config.speedup
            self._traffic_tick(now)
        for key, streams in self._links.items():  # each link its own streams
            self._current = key
            for msg_id, due in list(streams.next_due.items()):
                if due <= now + 1e-9:
                    interval = streams.intervals[msg_id] * self.config.speedup
                    built = self._builders[msg_id](now)
                    if built is not None:  # None: not available yet (no home before the fix)
                        self._send(built)
                    # Keep the cadence, but never queue a backlog after a stall.
                    streams.next_due[msg_id] = max(due + interval, now + 0.5 * interval)
        self._current = None
        up = self._upload
        if up is not None and now >= up.deadline:
            self._current = up.link  # the uploading client's link
            up.retries += 1
            if up.retries > 5:
                self.counters["mission_upload_timeout"] += 1
                self._send(mavlink.MAVLink_mission_ack_message(
                    up.peer[0], up.peer[1], MISSION_CANCELLED, up.mission_type))
                self._upload = None
            else:
                self._request_item(up, now)
        self._current = None

    def receive_datagram(self, data: bytes, addr: object, now: float,
                         link: Hashable = DEFAULT_LINK) -> None:
        """Decode and act on one datagram from ``addr`` on ``link``; bad bytes are counted,
        never raised."""
        if not self._running(now):
            self.counters["received_while_rebooting"] += 1  # nobody listens yet
            return
        if link not in self._links:
            self.counters["unknown_link"] += 1
            return
        self._current = link
        try:
            self._receive(data, addr, now - self._boot_at)
        finally:
            self._current = None
        if self._reboot_requested:  # the ACK is out first, as ArduPilot sends it
            self._reboot_requested = False
            self.rebooting_until = now + self.config.reboot_s * self.config.speedup

    def _running(self, now: float) -> bool:
        """False while rebooting; at its end, the vehicle boots again."""
        if self.rebooting_until is None:
            return True
        if now < self.rebooting_until:
            return False
        self._boot_at, self.rebooting_until = self.rebooting_until, None
        self.boots += 1
        self._boot(now - self._boot_at, autostart=False)
        return True

    def _receive(self, data: bytes, addr: object, now: float) -> None:
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
            if kind == "HEARTBEAT":
                frame = bytes(msg.get_msgbuf())
                for key, streams in self._links.items():
                    streams.forwards.append((addr if key == self._current else None, frame))
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
        """To the link being served (a reply, its streams), or every link outside one."""
        frame = msg.pack(self._tx)
        self._tx.seq = (self._tx.seq + 1) % 256
        streams = self._links.get(self._current) if self._current is not None else None
        for target in [streams] if streams is not None else self._links.values():
            target.out.append(frame)

    def _broadcast(self, msg: Any) -> None:
        current, self._current = self._current, None
        try:
            self._send(msg)
        finally:
            self._current = current

    def statustext(self, severity: int, text: str) -> None:
        self._broadcast(mavlink.MAVLink_statustext_message(severity, text[:50].encode(), 0, 0))

    def _drain_events(self, now: float) -> None:
        while (ev := self.fc.next_event()) is not None:
            if isinstance(ev, StatusText):
                self.statustext(ev.severity, ev.text)
            elif isinstance(ev, ItemReached):
                self._broadcast(mavlink.MAVLink_mission_item_reached_message(ev.seq))
            elif isinstance(ev, CurrentItemChanged):
                self._broadcast(self.telemetry.mission_current(now))
            elif isinstance(ev, ModeChanged):
                self._broadcast(self.telemetry.heartbeat(now))
            elif isinstance(ev, FixAcquired):
                # Both stacks announce home and origin to every link when they are set.
                if self.flavour.name == "ardupilot":
                    self.statustext(6, "EKF3 IMU0 is using GPS")
                    self.statustext(6, "EKF3 IMU0 origin set")
                self._broadcast(self.telemetry.gps_global_origin(now))
                self._broadcast(self.telemetry.home_position(now))
            elif isinstance(ev, HomeChanged):
                self._broadcast(self.telemetry.home_position(now))

    def _geo_to_ned(self, lat_deg: float, lon_deg: float, alt_rel_m: float
                    ) -> tuple[float, float, float]:
        home = self.config.home
        local = enu_from_geo(GeoPoint(lat_deg=lat_deg, lon_deg=lon_deg, alt_m=home.alt_m), home)
        return (local.north_m, local.east_m, -alt_rel_m)

    # ---------------------------------------------------------------------------- streams

    def set_interval(self, msg_id: int, interval_s: float | None, now: float) -> bool:
        """Stream ``msg_id`` every ``interval_s`` wall seconds, never faster than the
        autopilot's loop (None stops it); False if we lack it."""
        if msg_id not in self._builders:
            return False
        streams = self._links[DEFAULT_LINK if self._current is None else self._current]
        if interval_s is None:
            streams.intervals.pop(msg_id, None)
            streams.next_due.pop(msg_id, None)
        else:
            streams.intervals[msg_id] = max(interval_s, self.flavour.min_stream_interval_s)
            streams.next_due[msg_id] = now
        return True

    def interval_of(self, msg_id: int) -> float | None:
        """The requesting link's interval of ``msg_id`` (None: not streamed)."""
        link = DEFAULT_LINK if self._current is None else self._current
        return self._links[link].intervals.get(msg_id) if link in self._links else None

    # --------------------------------------------------------------------------- handlers

    def _on_heartbeat(self, msg: Any, now: float) -> None:
        self.gcs_heard = True

    # ------------------------------------------------------------------- data streams

    def _on_request_data_stream(self, msg: Any, now: float) -> None:
        if self.flavour.name != "ardupilot":
            self.counters["ignored_request_data_stream"] += 1
            return
        groups = list(STREAM_GROUPS) if msg.req_stream_id == 0 else [msg.req_stream_id]
        for group in groups:
            for msg_id in STREAM_GROUPS.get(group, ()):
                on = msg.start_stop and msg.req_message_rate > 0
                self.set_interval(msg_id, 1.0 / msg.req_message_rate if on else None, now)
