"""The simulated autopilot's traffic list: ADSB_VEHICLE in, as ArduPilot's AP_ADSB keeps it.

What the fake copies from ArduPilot (libraries/AP_ADSB/AP_ADSB.cpp) because a companion that
feeds it must cope with exactly this:

- ``ADSB_TYPE`` = 0 (the default) disables ADS-B: every ADSB_VEHICLE is ignored (counted
  ``adsb_disabled``). Any type > 0 enables MAVLink ADSB-in (5 = uAvionix-MAVLink-In).
  PX4 has no such switch: its MAVLink receiver always publishes ``transponder_report``.
- A vehicle's last update is ``now - tslc`` (time since last communication, whole
  seconds); a vehicle not updated for 5 s is dropped (VEHICLE_TIMEOUT_MS), and a report
  already older than that is ignored.
- Ignored and removed when tracked: lat/lon 0/0, ICAO address above 24 bits, our own ICAO
  (``ADSB_ICAO_ID``), neither ``ADSB_FLAGS_VALID_COORDS`` nor ``..._VALID_ALTITUDE`` set,
  farther than ``ADSB_LIST_RADIUS`` (2000 m on a copter, 0 = no filter) once we have a
  position, higher than ``ADSB_LIST_ALT`` metres when that is > 0.
- The list holds ``ADSB_LIST_MAX`` (25) vehicles, keyed by ICAO address; when full, a new
  vehicle replaces the farthest one only if it is closer.
- ``altitude`` is millimetres AMSL, ``heading`` centidegrees, ``hor_velocity`` cm/s,
  ``ver_velocity`` cm/s up (MAVLink common.xml).

Avoidance (off by default, ArduPilot AP_Avoidance): with ``AVD_ENABLE`` = 1 a vehicle in the
list closer than ``AVD_F_DIST_XY`` horizontally and ``AVD_F_DIST_Z`` vertically is a threat;
``AVD_F_ACTION`` 6 (hover) holds position, 2 (ascend or descend) moves away vertically to
``AVD_F_DIST_Z`` of separation; 0/1 only report. The fake acts once per threat and does not
model ArduPilot's recovery (``AVD_F_RCVRY``) or its time-to-closest-approach test.

Sans-I/O: positions are local NED metres of the simulation, time is an argument.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from sitl.geo import GeoPoint, enu_from_geo

__all__ = [
    "ADSB_FLAGS_VALID_ALTITUDE",
    "ADSB_FLAGS_VALID_COORDS",
    "TrafficList",
    "TrafficReport",
    "Vehicle",
]

VEHICLE_TIMEOUT_S = 5.0
MAX_ICAO = 0x00FFFFFF
ADSB_FLAGS_VALID_COORDS = 1
ADSB_FLAGS_VALID_ALTITUDE = 2
ADSB_FLAGS_VALID_HEADING = 4
ADSB_FLAGS_VALID_VELOCITY = 8
ADSB_FLAGS_VALID_CALLSIGN = 16


@dataclass(frozen=True, slots=True, kw_only=True)
class TrafficReport:
    """One ADSB_VEHICLE in SI units (decoded from MAVLink's scaled integers)."""

    icao_address: int
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    heading_deg: float
    hor_velocity_m_s: float
    ver_velocity_m_s: float
    callsign: str
    emitter_type: int
    tslc_s: int
    flags: int
    squawk: int = 0

    @classmethod
    def from_mavlink(cls, msg: Any) -> TrafficReport:
        raw = getattr(msg, "callsign", b"")
        callsign = raw.decode("ascii", "replace") if isinstance(raw, bytes) else str(raw)
        return cls(
            icao_address=int(msg.ICAO_address),
            lat_deg=int(msg.lat) / 1e7,
            lon_deg=int(msg.lon) / 1e7,
            alt_amsl_m=int(msg.altitude) / 1000.0,
            heading_deg=int(msg.heading) / 100.0,
            hor_velocity_m_s=int(msg.hor_velocity) / 100.0,
            ver_velocity_m_s=int(msg.ver_velocity) / 100.0,
            callsign=callsign.rstrip("\x00 "),
            emitter_type=int(msg.emitter_type),
            tslc_s=int(msg.tslc),
            flags=int(msg.flags),
            squawk=int(getattr(msg, "squawk", 0)),
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class Vehicle:
    """A tracked vehicle: the newest report and when it was last heard (``now - tslc``)."""

    report: TrafficReport
    last_update: float

    def age(self, now: float) -> float:
        return now - self.last_update


class TrafficList:
    """AP_ADSB's in_state: the vehicles the autopilot knows (module docstring)."""

    def __init__(self, *, list_max: int = 25, list_radius_m: float = 2000.0,
                 list_alt_m: float = 0.0, own_icao: int = 0) -> None:
        self.list_max = max(1, list_max)
        self.list_radius_m = list_radius_m
        self.list_alt_m = list_alt_m
        self.own_icao = own_icao
        self.vehicles: dict[int, Vehicle] = {}
        self.counters: dict[str, int] = {}

    def _count(self, key: str) -> None:
        self.counters[key] = self.counters.get(key, 0) + 1

    def handle(self, report: TrafficReport, *, now: float, home: GeoPoint,
               own_ned_m: tuple[float, float, float] | None) -> bool:
        """Track (or drop) one report; True when it is in the list afterwards."""
        last_update = now - report.tslc_s
        if not (abs(report.lat_deg) <= 90.0 and abs(report.lon_deg) <= 180.0):
            self._count("ignored_bad_position")
            self.vehicles.pop(report.icao_address, None)
            return False
        distance = None
        if own_ned_m is not None:
            distance = self.distance_m(report, home=home, own_ned_m=own_ned_m)
        reason = None
        if report.lat_deg == 0.0 and report.lon_deg == 0.0:
            reason = "zero_position"
        elif report.icao_address > MAX_ICAO:
            reason = "icao_over_24_bits"
        elif self.own_icao and report.icao_address == self.own_icao:
            reason = "ourself"
        elif not report.flags & (ADSB_FLAGS_VALID_COORDS | ADSB_FLAGS_VALID_ALTITUDE):
            reason = "no_valid_position_flags"
        elif now - last_update > VEHICLE_TIMEOUT_S:
            reason = "too_old"
        elif distance is not None and self.list_radius_m > 0 and distance > self.list_radius_m:
            reason = "out_of_radius"
        elif self.list_alt_m > 0 and report.alt_amsl_m > self.list_alt_m:
            reason = "above_list_alt"
        if reason is not None:
            self._count("ignored_" + reason)
            self.vehicles.pop(report.icao_address, None)
            return False
        vehicle = Vehicle(report=report, last_update=last_update)
        if report.icao_address in self.vehicles or len(self.vehicles) < self.list_max:
            self.vehicles[report.icao_address] = vehicle
            self._count("tracked")
            return True
        if own_ned_m is None or distance is None:
            self._count("ignored_list_full")
            return False
        farthest = max(self.vehicles.values(), key=lambda v: self.distance_m(
            v.report, home=home, own_ned_m=own_ned_m))
        if distance < self.distance_m(farthest.report, home=home, own_ned_m=own_ned_m):
            del self.vehicles[farthest.report.icao_address]
            self.vehicles[report.icao_address] = vehicle
            self._count("replaced_farthest")
            return True
        self._count("ignored_list_full")
        return False

    def expire(self, now: float) -> None:
        for icao in [i for i, v in self.vehicles.items() if v.age(now) > VEHICLE_TIMEOUT_S]:
            del self.vehicles[icao]
            self._count("timed_out")

    @staticmethod
    def relative_ned_m(report: TrafficReport, *, home: GeoPoint,
                       own_ned_m: tuple[float, float, float]) -> tuple[float, float, float]:
        """The other vehicle minus us, local NED metres."""
        enu = enu_from_geo(GeoPoint(lat_deg=report.lat_deg, lon_deg=report.lon_deg,
                                    alt_m=report.alt_amsl_m), home)
        return (enu.north_m - own_ned_m[0], enu.east_m - own_ned_m[1],
                -enu.up_m - own_ned_m[2])

    @classmethod
    def distance_m(cls, report: TrafficReport, *, home: GeoPoint,
                   own_ned_m: tuple[float, float, float]) -> float:
        dn, de, dd = cls.relative_ned_m(report, home=home, own_ned_m=own_ned_m)
        return math.sqrt(dn * dn + de * de + dd * dd)

    def snapshot(self, now: float) -> list[dict[str, object]]:
        """The list as tests and the vehicle's status read it (sorted by ICAO address)."""
        return [
            {"icao_address": v.report.icao_address, "callsign": v.report.callsign,
             "lat_deg": v.report.lat_deg, "lon_deg": v.report.lon_deg,
             "alt_amsl_m": v.report.alt_amsl_m, "emitter_type": v.report.emitter_type,
             "flags": v.report.flags, "age_s": round(v.age(now), 3)}
            for _, v in sorted(self.vehicles.items())
        ]


MAV_COLLISION_ACTION_ASCEND_OR_DESCEND = 2
MAV_COLLISION_ACTION_HOVER = 6


class TrafficAwareness:
    """The vehicle side: ADSB_VEHICLE handling by flavour, the list, avoidance (docstring).

    ``params`` is the vehicle's parameter table (read at every message, so a PARAM_SET takes
    effect at once; ArduPilot would want a reboot for ``ADSB_TYPE``), ``fc`` its flight
    controller.
    """

    def __init__(self, *, flavour: str, params: Any, fc: Any, home: GeoPoint) -> None:
        self.flavour = flavour
        self.params = params
        self.fc = fc
        self.home = home
        self.traffic = TrafficList()
        self.threats: set[int] = set()
        """ICAO addresses avoidance already acted on (once per threat)."""
        self.texts: list[tuple[int, str]] = []

    def _param(self, name: str, default: float) -> float:
        params = self.params
        if name in params:
            return float(params.get(name))
        return default

    def _own_ned(self) -> tuple[float, float, float] | None:
        if not getattr(self.fc, "has_fix", False):
            return None
        p = self.fc.state.position_ned_m
        return (float(p[0]), float(p[1]), float(p[2]))

    def enabled(self) -> bool:
        return self.flavour != "ardupilot" or self._param("ADSB_TYPE", 0) > 0

    def on_adsb_vehicle(self, msg: Any, now: float) -> None:
        if not self.enabled():
            self.traffic._count("adsb_disabled")
            return
        t = self.traffic
        if self.flavour == "ardupilot":
            t.list_max = max(1, int(self._param("ADSB_LIST_MAX", 25)))
            t.list_radius_m = self._param("ADSB_LIST_RADIUS", 2000)
            t.list_alt_m = self._param("ADSB_LIST_ALT", 0)
            t.own_icao = int(self._param("ADSB_ICAO_ID", 0))
        else:  # PX4 keeps no filtered list; the navigator sees every report
            t.list_max, t.list_radius_m, t.list_alt_m, t.own_icao = 100, 0.0, 0.0, 0
        t.handle(TrafficReport.from_mavlink(msg), now=now, home=self.home,
                 own_ned_m=self._own_ned())
        self.check_avoidance(now)

    def tick(self, now: float) -> None:
        self.traffic.expire(now)
        self.threats &= set(self.traffic.vehicles)

    def check_avoidance(self, now: float) -> None:
        """ArduPilot AP_Avoidance, simplified (module docstring); PX4 warns only."""
        own = self._own_ned()
        if own is None or self.fc.state.on_ground:
            return
        if self.flavour == "ardupilot":
            if self._param("AVD_ENABLE", 0) <= 0:
                return
            dist_xy, dist_z = self._param("AVD_F_DIST_XY", 100), self._param("AVD_F_DIST_Z", 100)
            action = int(self._param("AVD_F_ACTION", 1))
        else:
            if self._param("NAV_TRAFF_AVOID", 1) <= 0:
                return
            dist_xy, dist_z, action = self._param("NAV_TRAFF_A_RADU", 10.0), 500.0, 1
        for icao, vehicle in self.traffic.vehicles.items():
            dn, de, dd = TrafficList.relative_ned_m(vehicle.report, home=self.home,
                                                    own_ned_m=own)
            if math.hypot(dn, de) > dist_xy or abs(dd) > dist_z or icao in self.threats:
                continue
            self.threats.add(icao)
            name = vehicle.report.callsign or f"{icao:06X}"
            self.texts.append((4, f"Avoid: traffic {name} {math.hypot(dn, de):.0f}m"))
            fc = self.fc
            if action == MAV_COLLISION_ACTION_HOVER:
                fc.reposition(own)
            elif action == MAV_COLLISION_ACTION_ASCEND_OR_DESCEND:
                # away from the other: up when it is level or below (dd >= 0 means below)
                sign = -1.0 if dd >= 0 else 1.0
                climb = max(0.0, dist_z - abs(dd))
                fc.reposition((own[0], own[1], own[2] + sign * climb))
