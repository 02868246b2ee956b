"""What this drone knows about every other drone of the fleet, for its autopilot and its logic.

A companion on the shared medium (docs/peers.md) hears its peers' telemetry messages
(``position``, ``battery``, ``status``). :class:`PeerTable` keeps the latest state of each
peer with the time it was observed, and hands it out three ways:

- :meth:`PeerTable.snapshot` — JSON for the drone's own mission logic, served read-only by
  :class:`PeerHttp` at ``GET /peers`` (and ``GET /peers/<drone>``) on a local address;
- :meth:`PeerTable.adsb_reports` — one ADSB_VEHICLE per peer with a position, for the
  autopilot's traffic avoidance (ArduPilot AP_ADSB/AP_Avoidance, PX4 navigator), sent by
  :class:`AdsbInjector` at a configured rate (off by default);
- :attr:`PeerTable.peers` for tests and the status line.

**Identities on the ADS-B side.** ``icao_address`` is ``crc32(drone_id) & 0xFFFFFF`` (24
bits, never 0: 0 becomes 1); the callsign is the drone id upper-cased with anything but
A-Z and 0-9 removed, cut to 8 characters (the ADS-B callsign alphabet). ``tslc`` is the
position's age in whole seconds (0..255), so an autopilot drops a peer that stopped
reporting: ArduPilot after 5 s (VEHICLE_TIMEOUT_MS), as it would a silent transponder.

**Ages.** A peer's position is observed at its message's ``t_gen`` minus its ``pose_age_s``
(the fleet's clocks are chrony-synchronised; an observation "in the future" counts as age 0).
Velocity comes from the message (``vn_m_s``, ``ve_m_s``, ``vd_m_s``) when present, else
from the last two positions.

The table is sans-I/O (every call takes ``now``); the two shells are thin.
"""

from __future__ import annotations

import logging
import math
import re
import zlib
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from utility_specs.data_fields import first_number
from utility_specs.message import Message

__all__ = ["AdsbReport", "PeerState", "PeerTable", "callsign_for", "icao_for"]

log = logging.getLogger("companion.peers")  # one logger name for the peer services

ADSB_FLAGS_VALID_COORDS = 1
ADSB_FLAGS_VALID_ALTITUDE = 2
ADSB_FLAGS_VALID_HEADING = 4
ADSB_FLAGS_VALID_VELOCITY = 8
ADSB_FLAGS_VALID_CALLSIGN = 16
ADSB_ALTITUDE_TYPE_GEOMETRIC = 1
"""The altitude is from GNSS (AMSL), not a pressure altitude."""
ADSB_EMITTER_TYPE_UAV = 14
MAX_PEERS = 256
"""Peers kept; a new one beyond this evicts the least recently heard."""
MAX_FUTURE_S = 2.0
"""A message's ``t_gen`` counts as at most this far ahead of our clock (GPS/NTP-synced fleet
clocks differ by milliseconds): a forged far-future time no longer freezes a peer's position
(every true one after it was ``older_position``) for longer than this."""
MAX_STATUS_PEERS = 32
"""Peers whose ages a status message carries at most (the most recently heard)."""
_CALLSIGN_DROP = re.compile(r"[^A-Z0-9]")


def icao_for(drone_id: str) -> int:
    """24-bit ICAO address of a drone (module docstring)."""
    return (zlib.crc32(drone_id.encode()) & 0xFFFFFF) or 1


def callsign_for(drone_id: str) -> str:
    """ADS-B callsign of a drone: A-Z, 0-9, at most 8 characters."""
    return _CALLSIGN_DROP.sub("", drone_id.upper())[:8] or "UAV"


@dataclass(frozen=True, slots=True, kw_only=True)
class PeerState:
    """The latest of one peer; ``t_*`` are fleet-clock observation times (None: never)."""

    drone: str
    t_heard: float
    lat_deg: float | None = None
    lon_deg: float | None = None
    alt_rel_m: float | None = None
    alt_amsl_m: float | None = None
    heading_deg: float | None = None
    velocity_ned_m_s: tuple[float, float, float] | None = None
    t_position: float | None = None
    battery: float | None = None
    t_battery: float | None = None
    status: Mapping[str, Any] = field(default_factory=dict)
    t_status: float | None = None

    def age(self, t: float | None, now: float) -> float | None:
        return None if t is None else max(0.0, now - t)

    def to_json(self, now: float) -> dict[str, Any]:
        return {
            "drone": self.drone,
            "heard_age_s": round(max(0.0, now - self.t_heard), 3),
            "position": None if self.t_position is None else {
                "lat_deg": self.lat_deg, "lon_deg": self.lon_deg, "alt_rel_m": self.alt_rel_m,
                "alt_amsl_m": self.alt_amsl_m, "heading_deg": self.heading_deg,
                "velocity_ned_m_s": (list(self.velocity_ned_m_s)
                                     if self.velocity_ned_m_s is not None else None),
                "age_s": round(max(0.0, now - self.t_position), 3)},
            "battery": None if self.t_battery is None else {
                "level": self.battery, "age_s": round(max(0.0, now - self.t_battery), 3)},
            "status": None if self.t_status is None else {
                **dict(self.status), "age_s": round(max(0.0, now - self.t_status), 3)},
        }


@dataclass(frozen=True, slots=True, kw_only=True)
class AdsbReport:
    """ADSB_VEHICLE fields in MAVLink's units, ready for ``MAVLink_adsb_vehicle_message``."""

    icao_address: int
    lat: int
    lon: int
    altitude_type: int
    altitude: int
    heading: int
    hor_velocity: int
    ver_velocity: int
    callsign: bytes
    emitter_type: int
    tslc: int
    flags: int
    squawk: int = 0

    def args(self) -> tuple[Any, ...]:
        """Positional arguments of pymavlink's ``MAVLink_adsb_vehicle_message``."""
        return (self.icao_address, self.lat, self.lon, self.altitude_type, self.altitude,
                self.heading, self.hor_velocity, self.ver_velocity, self.callsign,
                self.emitter_type, self.tslc, self.flags, self.squawk)


def _clamped(value: float, low: int, high: int) -> int:
    """``value`` rounded into a MAVLink integer field. A peer's message may hold any finite
    number (1e308 m/s): unclamped, it overflowed to inf and ``round`` raised, which stopped
    the ADSB_VEHICLE injection of every peer."""
    return low if math.isnan(value) else round(max(low, min(high, value)))


class PeerTable:
    """Latest state of every peer (sans-I/O; module docstring)."""

    def __init__(self, own_id: str, *, forget_after_s: float = 60.0,
                 max_peers: int = MAX_PEERS) -> None:
        self.own_id = own_id
        self.forget_after_s = forget_after_s
        self.max_peers = max_peers
        self.peers: dict[str, PeerState] = {}
        self.counters: dict[str, int] = {}

    def _count(self, key: str) -> None:
        self.counters[key] = self.counters.get(key, 0) + 1

    def on_message(self, message: Message, *, now: float) -> None:
        """One reassembled message from the medium; our own and unknown types are ignored."""
        if message.sender == self.own_id:
            self._count("own")
            return
        data = message.data
        peer = self.peers.pop(message.sender, None)
        if peer is None:
            if len(self.peers) >= self.max_peers:
                del self.peers[next(iter(self.peers))]
                self._count("evicted")
            peer = PeerState(drone=message.sender, t_heard=now)
            log.info("peer %s heard", message.sender)
        peer = replace(peer, t_heard=max(peer.t_heard, now))
        t_obs = message.t_gen
        if t_obs > now + MAX_FUTURE_S:
            t_obs = now + MAX_FUTURE_S
            self._count("future_t_gen")
        if message.type == "position" or first_number(data, "lat_deg") is not None:
            pose_age = max(0.0, first_number(data, "pose_age_s") or 0.0)
            peer = self._position(peer, data, t_obs - pose_age)
        if message.type == "battery":
            level = first_number(data, "level")
            if level is not None and (peer.t_battery is None or t_obs >= peer.t_battery):
                peer = replace(peer, battery=level, t_battery=t_obs)
        if message.type == "status" and (peer.t_status is None or t_obs >= peer.t_status):
            keep = ("mode", "armed", "failsafe", "mission", "autopilot", "connected",
                    "fix_type")
            peer = replace(peer, status={k: data[k] for k in keep if k in data},
                           t_status=t_obs)
        self.peers[message.sender] = peer  # most recently heard last
        self._count(message.type if message.type in ("position", "battery", "status")
                    else "other")

    def _position(self, peer: PeerState, data: Mapping[str, Any], t_obs: float) -> PeerState:
        lat, lon = first_number(data, "lat_deg"), first_number(data, "lon_deg")
        if lat is None or lon is None or not (abs(lat) <= 90 and abs(lon) <= 180):
            self._count("no_position")
            return peer
        if peer.t_position is not None and t_obs <= peer.t_position:
            self._count("older_position")
            return peer
        velocity: tuple[float, float, float] | None = None
        vn, ve, vd = (first_number(data, k) for k in ("vn_m_s", "ve_m_s", "vd_m_s"))
        alt_rel = first_number(data, "alt_rel_m", "alt_m")
        if vn is not None and ve is not None:
            velocity = (vn, ve, vd or 0.0)
        elif (peer.t_position is not None and peer.lat_deg is not None
              and peer.lon_deg is not None and 0.0 < t_obs - peer.t_position <= 10.0):
            dt = t_obs - peer.t_position
            r = 6_371_000.0
            dn = math.radians(lat - peer.lat_deg) * r
            de = math.radians(lon - peer.lon_deg) * r * math.cos(math.radians(lat))
            dd = 0.0
            if alt_rel is not None and peer.alt_rel_m is not None:
                dd = -(alt_rel - peer.alt_rel_m)
            velocity = (dn / dt, de / dt, dd / dt)
        return replace(peer, lat_deg=lat, lon_deg=lon, alt_rel_m=alt_rel,
                       alt_amsl_m=first_number(data, "alt_amsl_m"),
                       heading_deg=first_number(data, "heading_deg"), velocity_ned_m_s=velocity,
                       t_position=t_obs)

    def forget_silent(self, now: float) -> list[str]:
        gone = [d for d, p in self.peers.items() if now - p.t_heard > self.forget_after_s]
        for drone in gone:
            del self.peers[drone]
            self._count("forgotten")
        return gone

    def snapshot(self, now: float) -> dict[str, Any]:
        """What ``GET /peers`` returns."""
        return {"drone": self.own_id, "t": now,
                "peers": [self.peers[d].to_json(now) for d in sorted(self.peers)]}

    def ages(self, now: float, *, limit: int = MAX_STATUS_PEERS) -> dict[str, float]:
        """Per peer, the age of its position (of its last word when it sent none), 0.1 s
        resolution: the compact map a status message carries to the dashboard. At most
        ``limit``, the most recently heard."""
        out: dict[str, float] = {}
        for drone, peer in list(self.peers.items())[-limit:]:
            age = peer.age(peer.t_position, now)
            if age is None:
                age = max(0.0, now - peer.t_heard)
            out[drone] = round(age, 1)
        return out

    def adsb_reports(self, now: float) -> list[AdsbReport]:
        """One ADSB_VEHICLE per peer with a position (module docstring)."""
        reports = []
        for drone in sorted(self.peers):
            p = self.peers[drone]
            if p.t_position is None or p.lat_deg is None or p.lon_deg is None:
                continue
            flags = ADSB_FLAGS_VALID_COORDS | ADSB_FLAGS_VALID_CALLSIGN
            altitude = 0
            amsl = p.alt_amsl_m
            if amsl is not None:
                flags |= ADSB_FLAGS_VALID_ALTITUDE
                altitude = _clamped(amsl * 1000, -2**31, 2**31 - 1)  # int32 mm
            heading = p.heading_deg
            hor = ver = 0
            if p.velocity_ned_m_s is not None:
                vn, ve, vd = p.velocity_ned_m_s
                flags |= ADSB_FLAGS_VALID_VELOCITY
                hor = _clamped(math.hypot(vn, ve) * 100, 0, 65535)
                ver = _clamped(-vd * 100, -32768, 32767)
                if math.hypot(vn, ve) > 0.5:  # course over ground when moving
                    heading = math.degrees(math.atan2(ve, vn)) % 360
            if heading is not None:
                flags |= ADSB_FLAGS_VALID_HEADING
            reports.append(AdsbReport(
                icao_address=icao_for(drone), lat=round(p.lat_deg * 1e7),
                lon=round(p.lon_deg * 1e7), altitude_type=ADSB_ALTITUDE_TYPE_GEOMETRIC,
                altitude=altitude,
                heading=0 if heading is None else round(heading % 360 * 100) % 36000,
                hor_velocity=hor, ver_velocity=ver, callsign=callsign_for(drone).encode(),
                emitter_type=ADSB_EMITTER_TYPE_UAV,
                tslc=min(255, int(max(0.0, now - p.t_position))), flags=flags))
        return reports

