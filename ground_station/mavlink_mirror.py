"""The fleet in any MAVLink ground station: each drone's telemetry re-emitted as MAVLink 2.

QGroundControl, Mission Planner and MAVProxy show one vehicle per MAVLink system id; this
module makes the ground station look like a router with every drone of the fleet behind it.
For each drone heard it sends, from the drone's own system id (component 1):

- HEARTBEAT once a second while the drone is heard (silence longer than ``link_lost_s``, or
  2.5 of the status periods the drone says it keeps, stops it, so the GCS shows that
  vehicle's link lost, as it would for a real one);
- GLOBAL_POSITION_INT and ATTITUDE when a new position arrives, and once a second;
- SYS_STATUS, BATTERY_STATUS and GPS_RAW_INT once a second;
- STATUSTEXT for every autopilot message the drone forwarded (its ``statustext``).

**System ids** (:func:`system_id_for`): a drone id ending in a number 1..250 (``drone7``,
``uav-12``) gets that number; any other id gets ``1 + crc32(id) % 250``. A second drone
deriving an id already in use takes the next free one (1..250 wrap around), so ids are
unique for the life of the process. 251..255 stay free for ground stations (MAVProxy and
QGC use 255).

**Read-only.** Nothing received on this endpoint reaches a drone. A client's HEARTBEAT
makes it a destination (like a vehicle's link) until it is silent for ``CLIENT_TIMEOUT_S``;
at most ``max_clients`` at once, and a newcomer beyond that is refused, never put in the
place of a client still sending (anyone who can reach the port can send a HEARTBEAT). Each
datagram is parsed on its own, as MAVLink over UDP is sent: one client's torn frame never
swallows another's. MISSION_REQUEST_LIST
is answered with an empty mission (MISSION_COUNT 0) and every COMMAND_LONG/COMMAND_INT with
COMMAND_ACK ``MAV_RESULT_DENIED``, so a GCS finishes loading and gets an explicit refusal
instead of timeouts; everything else (mode changes, mission uploads, parameter writes,
setpoints) is counted in ``counters["ignored_<TYPE>"]`` and dropped.

:class:`MavlinkMirror` is the sans-I/O core (time is an argument); :class:`MavlinkOut` is
the asyncio UDP shell. Enabled by the ground-station config keys ``mavlink_out`` (a
``HOST:PORT`` to push to, e.g. QGC's 14550) and/or ``mavlink_listen`` (a ``HOST:PORT`` to
bind, for clients that connect, e.g. ``mavproxy.py --master=udpout:HOST:PORT``); off when
neither is set. See docs/peers.md.
"""

from __future__ import annotations

import logging
import math
import re
import zlib
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, cast

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ground_station.drone_state import declared_status_period, lost_after_s
from ground_station.mavlink_signing import SignedFrames
from utility_specs.data_fields import first_number

__all__ = ["Addr", "MavlinkMirror", "parse_endpoint", "system_id_for"]

log = logging.getLogger("ground_station.mavlink_out")  # one logger name for the endpoint

Addr = tuple[str, int]

MAX_SYSTEM_ID = 250
"""Drones get 1..250; 251..255 are left to ground stations."""
PERIOD_S = 1.0
CLIENT_TIMEOUT_S = 10.0
"""A client silent this long (a GCS sends a HEARTBEAT every second) is no destination."""
MAV_RESULT_DENIED = 2
MAV_TYPE_QUADROTOR = 2
MAV_AUTOPILOT_GENERIC = 0
MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_AUTOPILOT_PX4 = 12
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_MODE_FLAG_SAFETY_ARMED = 128
MAV_STATE_STANDBY = 3
MAV_STATE_ACTIVE = 4
MAV_STATE_CRITICAL = 5
MAV_TYPE_GCS = 6
UINT16_MAX = 65535
INT16_MAX = 32767

_TRAILING_NUMBER = re.compile(r"(\d+)$")


def system_id_for(drone_id: str, taken: Mapping[int, str] | None = None) -> int:
    """The MAVLink system id of a drone (module docstring); ``taken`` maps ids in use to
    the drones holding them, and a collision moves on to the next free id."""
    match = _TRAILING_NUMBER.search(drone_id)
    number = int(match.group(1)) if match else 0
    base = number if 1 <= number <= MAX_SYSTEM_ID else 1 + zlib.crc32(drone_id.encode()) % (
        MAX_SYSTEM_ID)
    taken = taken or {}
    for step in range(MAX_SYSTEM_ID):
        candidate = (base - 1 + step) % MAX_SYSTEM_ID + 1
        if taken.get(candidate, drone_id) == drone_id:
            return candidate
    raise ValueError("all 250 MAVLink system ids are in use")


def parse_endpoint(text: str) -> Addr:
    """``HOST:PORT`` -> (host, port); ValueError with a one-line reason otherwise."""
    host, sep, port_text = text.rpartition(":")
    if not sep or not host or not port_text.isdigit() or not 0 <= int(port_text) < 65536:
        raise ValueError(f"expected HOST:PORT with a port 0..65535, got {text!r}")
    return host, int(port_text)


def _clamp_int(value: float, low: int, high: int) -> int:
    return max(low, min(high, round(value)))


def _custom_mode(autopilot: str | None, mode: str | None) -> tuple[int, int]:
    """(MAV_AUTOPILOT, custom_mode) for a mode name as the companion reports it."""
    from pymavlink import mavutil

    if autopilot == "ardupilot":
        by_name = {name: number for number, name in mavutil.mode_mapping_acm.items()}
        return MAV_AUTOPILOT_ARDUPILOTMEGA, by_name.get(mode or "", 0)
    if autopilot == "px4":
        px4 = getattr(mavutil, "px4_map", {})
        entry = px4.get(mode or "")
        if entry is not None:
            _base, main, sub = entry
            return MAV_AUTOPILOT_PX4, (main << 16) | (sub << 24)
        return MAV_AUTOPILOT_PX4, 0
    return MAV_AUTOPILOT_GENERIC, 0


@dataclass(slots=True)
class _Drone:
    drone: str
    system_id: int
    encoder: Any
    last_heard: float
    data: dict[str, Any] = field(default_factory=dict)
    texts: list[tuple[int, str]] = field(default_factory=list)
    next_period: float = 0.0
    position_new: bool = False


class MavlinkMirror:
    """Sans-I/O: drone data in, MAVLink 2 frames out (module docstring)."""

    def __init__(self, *, now: float, link_lost_s: float = 3.0, max_clients: int = 8,
                 max_drones: int = MAX_SYSTEM_ID, signing_key: bytes | None = None) -> None:
        self.link_lost_s = link_lost_s
        self.max_clients = max_clients
        self.max_drones = max_drones
        self.drones: dict[str, _Drone] = {}
        self.clients: dict[Addr, float] = {}
        """Addresses that sent us a HEARTBEAT -> when (most recent last)."""
        self.counters: Counter[str] = Counter()
        self._out: list[tuple[bytes, Addr | None]] = []
        self._now = now
        self.signing = SignedFrames(signing_key) if signing_key is not None else None

    @staticmethod
    def _new_parser() -> Any:
        parser = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
        parser.robust_parsing = True
        return parser

    # -- input from the fleet -----------------------------------------------------------
    def on_data(self, drone: str, data: Mapping[str, Any], *, now: float) -> None:
        """One message's or status's data from ``drone`` (the fleet view's field names)."""
        state = self.drones.get(drone)
        if state is None:
            if len(self.drones) >= self.max_drones:
                self.counters["drones_refused"] += 1
                return
            taken = {d.system_id: d.drone for d in self.drones.values()}
            sysid = system_id_for(drone, taken)
            encoder = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=1)
            if self.signing is not None:
                self.signing.sign_with(encoder)
            state = _Drone(drone=drone, system_id=sysid, encoder=encoder, last_heard=now,
                           next_period=now)
            self.drones[drone] = state
            log.info("MAVLink out: %s is system id %d", drone, sysid)
        state.last_heard = now
        self._now = now
        for key, value in data.items():
            if key in ("statustext", "text"):
                continue
            state.data[key] = value
        text = data.get("statustext", data.get("text"))
        if isinstance(text, str) and text:
            severity = first_number(data, "severity")
            state.texts.append((_clamp_int(severity if severity is not None else 6, 0, 7),
                                text))
            del state.texts[:-20]
        if first_number(data, "lat_deg") is not None and first_number(data, "lon_deg") is not None:
            state.position_new = True
        self._emit_due(now)

    # -- input from GCS clients ---------------------------------------------------------
    def receive_datagram(self, data: bytes, addr: Addr, now: float) -> None:
        # A parser of its own per datagram: a shared one kept a torn frame's bytes (10 from
        # anyone) and read the next client's datagram as that frame's payload.
        self._now = now
        try:
            msgs = self._new_parser().parse_buffer(data) or []
        except mavlink.MAVError:
            self.counters["malformed"] += 1
            return
        for msg in msgs:
            kind = msg.get_type()
            if self.signing is not None and kind != "BAD_DATA":
                refusal = self.signing.check(msg, now)
                if refusal is not None:  # nothing unsigned is answered, nobody is added
                    self.counters[refusal] += 1
                    continue
            if kind == "BAD_DATA":
                self.counters["bad_data"] += 1
            elif kind == "HEARTBEAT":
                self._client_heartbeat(addr, now)
            elif kind == "MISSION_REQUEST_LIST":
                target = self._target(msg)
                if target is not None:
                    self._send(target, mavlink.MAVLink_mission_count_message(
                        msg.get_srcSystem(), msg.get_srcComponent(), 0,
                        getattr(msg, "mission_type", 0)), addr)
                    self.counters["answered_mission_request_list"] += 1
            elif kind in ("COMMAND_LONG", "COMMAND_INT"):
                target = self._target(msg)
                if target is not None:
                    self._send(target, mavlink.MAVLink_command_ack_message(
                        msg.command, MAV_RESULT_DENIED, 0, 0, msg.get_srcSystem(),
                        msg.get_srcComponent()), addr)
                    self.counters["denied_" + kind.lower()] += 1
            else:  # message ids are 24 bits: unknown ones share one counter
                self.counters["ignored_unknown" if kind.startswith("UNKNOWN")
                              else "ignored_" + kind] += 1

    def _client_heartbeat(self, addr: Addr, now: float) -> None:
        live = self.live_clients(now)
        if addr not in self.clients and len(live) >= self.max_clients:
            self.counters["clients_refused"] += 1  # the live ones keep their place
            return
        self.clients[addr] = now
        self.counters["client_heartbeats"] += 1

    def live_clients(self, now: float) -> list[Addr]:
        """The destinations now: clients heard within ``CLIENT_TIMEOUT_S`` (others dropped)."""
        for addr in [a for a, t in self.clients.items() if now - t > CLIENT_TIMEOUT_S]:
            del self.clients[addr]
        return list(self.clients)

    def _target(self, msg: Any) -> _Drone | None:
        sysid = getattr(msg, "target_system", 0)
        for state in self.drones.values():
            if state.system_id == sysid:
                return state
        self.counters["not_a_drone"] += 1
        return None

    # -- timer ----------------------------------------------------------------------------
    def get_timer(self) -> float | None:
        live = [d.next_period for d in self.drones.values()]
        return min(live) if live else None

    def handle_timer(self, now: float) -> None:
        self._now = now
        self._emit_due(now)

    def datagrams_to_send(self) -> list[tuple[bytes, Addr | None]]:
        """(frame, address): address None means every destination."""
        out, self._out = self._out, []
        return out

    # -- output ---------------------------------------------------------------------------
    def _send(self, state: _Drone, msg: Any, addr: Addr | None = None) -> None:
        if self.signing is not None:
            self.signing.advance(state.encoder, self._now)
        self._out.append((msg.pack(state.encoder), addr))
        state.encoder.seq = (state.encoder.seq + 1) % 256
        self.counters["frames"] += 1

    def _emit_due(self, now: float) -> None:
        for state in self.drones.values():
            silent = now - state.last_heard > lost_after_s(
                self.link_lost_s, declared_status_period(state.data))
            periodic = now >= state.next_period
            if periodic:
                state.next_period = max(state.next_period + PERIOD_S, now + 0.5 * PERIOD_S)
            if silent:
                continue
            if periodic:
                self._heartbeat(state)
                self._sys_status(state)
                self._battery(state)
                self._gps(state)
            if periodic or state.position_new:
                state.position_new = False
                self._position(state, now)
                self._attitude(state, now)
            for severity, text in state.texts:
                for start in range(0, len(text), 50):
                    self._send(state, mavlink.MAVLink_statustext_message(
                        severity, text[start:start + 50].encode(), 0, 0))
            state.texts.clear()

    def _heartbeat(self, state: _Drone) -> None:
        data = state.data
        autopilot, custom = _custom_mode(cast(str | None, data.get("autopilot")),
                                         cast(str | None, data.get("mode")))
        armed = data.get("armed") is True
        base = MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
        status = MAV_STATE_ACTIVE if armed else MAV_STATE_STANDBY
        if data.get("failsafe") is True:
            status = MAV_STATE_CRITICAL
        self._send(state, mavlink.MAVLink_heartbeat_message(
            MAV_TYPE_QUADROTOR, autopilot, base, custom, status, 3))

    def _position(self, state: _Drone, now: float) -> None:
        data = state.data
        lat, lon = first_number(data, "lat_deg"), first_number(data, "lon_deg")
        if lat is None or lon is None:
            return
        rel = first_number(data, "alt_rel_m", "alt_m") or 0.0
        amsl = first_number(data, "alt_amsl_m")
        amsl = rel if amsl is None else amsl
        heading = first_number(data, "heading_deg")
        vn, ve, vd = (first_number(data, k) or 0.0 for k in ("vn_m_s", "ve_m_s", "vd_m_s"))
        self._send(state, mavlink.MAVLink_global_position_int_message(
            _boot_ms(now), _clamp_int(lat * 1e7, -900000000, 900000000),
            _clamp_int(lon * 1e7, -1800000000, 1800000000),
            _clamp_int(amsl * 1000, -2**31, 2**31 - 1), _clamp_int(rel * 1000, -2**31, 2**31 - 1),
            _clamp_int(vn * 100, -INT16_MAX, INT16_MAX), _clamp_int(ve * 100, -INT16_MAX,
                                                                  INT16_MAX),
            _clamp_int(vd * 100, -INT16_MAX, INT16_MAX),
            UINT16_MAX if heading is None else _clamp_int((heading % 360) * 100, 0, 35999)))

    def _attitude(self, state: _Drone, now: float) -> None:
        data = state.data
        roll, pitch = first_number(data, "roll_rad"), first_number(data, "pitch_rad")
        yaw = first_number(data, "yaw_rad")
        if yaw is None and (heading := first_number(data, "heading_deg")) is not None:
            yaw = math.radians(heading)
        if roll is None and pitch is None and yaw is None:
            return
        yaw = yaw or 0.0
        yaw = math.atan2(math.sin(yaw), math.cos(yaw))  # MAVLink's -pi..pi
        self._send(state, mavlink.MAVLink_attitude_message(
            _boot_ms(now), roll or 0.0, pitch or 0.0, yaw, 0.0, 0.0, 0.0))

    def _level(self, state: _Drone) -> int:
        level = first_number(state.data, "level", "battery")
        if level is None:
            return -1
        return _clamp_int(level if level > 1.0 else level * 100, 0, 100)

    def _sys_status(self, state: _Drone) -> None:
        volts = first_number(state.data, "battery_v")
        mv = UINT16_MAX if volts is None else _clamp_int(volts * 1000, 0, UINT16_MAX - 1)
        self._send(state, mavlink.MAVLink_sys_status_message(
            0, 0, 0, 0, mv, -1, self._level(state), 0, 0, 0, 0, 0, 0))

    def _battery(self, state: _Drone) -> None:
        volts = first_number(state.data, "battery_v")
        mv = UINT16_MAX if volts is None else _clamp_int(volts * 1000, 0, UINT16_MAX - 1)
        self._send(state, mavlink.MAVLink_battery_status_message(
            0, 0, 0, INT16_MAX, [mv] + [UINT16_MAX] * 9, -1, -1, -1, self._level(state)))

    def _gps(self, state: _Drone) -> None:
        data = state.data
        fix = first_number(data, "fix_type", "gps_fix")
        lat, lon = first_number(data, "lat_deg"), first_number(data, "lon_deg")
        amsl = first_number(data, "alt_amsl_m", "alt_rel_m") or 0.0
        self._send(state, mavlink.MAVLink_gps_raw_int_message(
            0, _clamp_int(fix or 0, 0, 8),
            0 if lat is None else _clamp_int(lat * 1e7, -900000000, 900000000),
            0 if lon is None else _clamp_int(lon * 1e7, -1800000000, 1800000000),
            _clamp_int(amsl * 1000, -2**31, 2**31 - 1), UINT16_MAX, UINT16_MAX, UINT16_MAX,
            UINT16_MAX, 255))


def _boot_ms(now: float) -> int:
    """time_boot_ms wraps at 2**32 ms; the Unix clock modulo that is monotonic enough."""
    return int(now * 1000) % (2**32)
