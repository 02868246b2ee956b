"""Mission items and the target positions they name, independent of MAVLink encoding."""

from __future__ import annotations

import math
from dataclasses import dataclass

from sitl.geo import GeoPoint, enu_from_geo

__all__ = [
    "CMD_CHANGE_SPEED",
    "CMD_LAND",
    "CMD_LOITER_TIME",
    "CMD_LOITER_UNLIM",
    "CMD_RTL",
    "CMD_SET_ROI",
    "CMD_SET_ROI_LOCATION",
    "CMD_SET_ROI_NONE",
    "CMD_TAKEOFF",
    "CMD_WAYPOINT",
    "FRAME_GLOBAL",
    "FRAME_GLOBAL_INT",
    "FRAME_GLOBAL_RELATIVE_ALT",
    "FRAME_GLOBAL_RELATIVE_ALT_INT",
    "FRAME_MISSION",
    "MissionItem",
    "is_nav_command",
]

CMD_WAYPOINT = 16
CMD_LOITER_UNLIM = 17
CMD_LOITER_TIME = 19
CMD_RTL = 20
CMD_LAND = 21
CMD_TAKEOFF = 22
CMD_CHANGE_SPEED = 178
CMD_SET_ROI_LOCATION = 195
CMD_SET_ROI_NONE = 197
CMD_SET_ROI = 201  # deprecated form: param1 = MAV_ROI (3 = location)

FRAME_GLOBAL = 0
FRAME_LOCAL_NED = 1
FRAME_MISSION = 2
FRAME_GLOBAL_RELATIVE_ALT = 3
FRAME_GLOBAL_INT = 5
FRAME_GLOBAL_RELATIVE_ALT_INT = 6
FRAME_GLOBAL_TERRAIN_ALT = 10
FRAME_GLOBAL_TERRAIN_ALT_INT = 11

GLOBAL_FRAMES = frozenset({FRAME_GLOBAL, FRAME_GLOBAL_INT})
RELATIVE_FRAMES = frozenset({FRAME_GLOBAL_RELATIVE_ALT, FRAME_GLOBAL_RELATIVE_ALT_INT,
                             FRAME_GLOBAL_TERRAIN_ALT, FRAME_GLOBAL_TERRAIN_ALT_INT})
"""Altitude above home; terrain frames are flown as relative (the simulated ground is flat)."""


def commanded_alt_rel_m(frame: int | None, alt_m: float, home: GeoPoint) -> float:
    """Altitude above home of a command's altitude: relative frames as is, any other (or no)
    frame as AMSL, as autopilots read COMMAND_LONG and global setpoints."""
    return alt_m if frame in RELATIVE_FRAMES else alt_m - home.alt_m


def is_nav_command(command: int) -> bool:
    """MAV_CMD_NAV_* occupy ids below 95 (MAV_CMD_NAV_LAST); they are the ones 'reached'."""
    return command < 95


@dataclass(frozen=True, slots=True, kw_only=True)
class MissionItem:
    """One MISSION_ITEM_INT in SI units: latitude/longitude in degrees, z in metres."""

    seq: int
    frame: int
    command: int
    current: int = 0
    autocontinue: int = 1
    param1: float = 0.0
    param2: float = 0.0
    param3: float = 0.0
    param4: float = 0.0
    lat_deg: float = 0.0
    lon_deg: float = 0.0
    z_m: float = 0.0
    mission_type: int = 0

    @property
    def has_position(self) -> bool:
        return self.frame in GLOBAL_FRAMES | RELATIVE_FRAMES and not (
            self.lat_deg == 0.0 and self.lon_deg == 0.0
        )

    def alt_rel_m(self, home: GeoPoint) -> float:
        """Altitude above home: relative frames as is, AMSL frames minus home's altitude."""
        if self.frame in GLOBAL_FRAMES:
            return self.z_m - home.alt_m
        return self.z_m

    def target_ned_m(self, home: GeoPoint, here_ned_m: tuple[float, float, float]
                     ) -> tuple[float, float, float]:
        """Where this item sends the vehicle (local NED); no lat/lon keeps the current spot."""
        alt = self.alt_rel_m(home)
        if not math.isfinite(alt):
            alt = -here_ned_m[2]
        if not self.has_position:
            return (here_ned_m[0], here_ned_m[1], -alt)
        local = enu_from_geo(GeoPoint(lat_deg=self.lat_deg, lon_deg=self.lon_deg,
                                      alt_m=home.alt_m), home)
        return (local.north_m, local.east_m, -alt)
