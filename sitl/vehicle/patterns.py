"""Flight patterns as mission items: lawnmower survey, orbit around a point, waypoint files.

Positions are given in the scene's local ENU metres around ``origin`` and converted to
lat/lon, so a pattern and the synthetic camera's scene agree on where things are.
Every pattern starts with a takeoff and ends with RTL; ArduPilot-flavoured missions get the
home placeholder as item 0 (``item0_is_home``).
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

from sitl.geo import Enu, GeoPoint, geo_from_enu
from sitl.vehicle.mission import (
    CMD_CHANGE_SPEED,
    CMD_RTL,
    CMD_SET_ROI_LOCATION,
    CMD_SET_ROI_NONE,
    CMD_TAKEOFF,
    CMD_WAYPOINT,
    FRAME_GLOBAL,
    FRAME_GLOBAL_RELATIVE_ALT_INT,
    FRAME_MISSION,
    MissionItem,
)

__all__ = ["PatternError", "load_waypoints", "orbit", "survey", "wrap_mission"]


class PatternError(ValueError):
    """A pattern that cannot be flown or a waypoint file that cannot be read."""


def wrap_mission(
    points: list[GeoPoint], *, home: GeoPoint, alt_m: float, speed_m_s: float | None,
    item0_is_home: bool, hold_s: float = 0.0, roi: GeoPoint | None = None,
) -> list[MissionItem]:
    """Takeoff, optional speed change, the waypoints (alt relative to home), RTL.

    With ``roi`` (region of interest, alt relative to home) the waypoints are bracketed by
    DO_SET_ROI_LOCATION / DO_SET_ROI_NONE: the vehicle keeps its nose towards that point.
    """
    items: list[MissionItem] = []

    def add(**kw: float | int) -> None:
        items.append(MissionItem(seq=len(items), **kw))  # type: ignore[arg-type]

    if item0_is_home:
        add(frame=FRAME_GLOBAL, command=CMD_WAYPOINT, lat_deg=home.lat_deg,
            lon_deg=home.lon_deg, z_m=home.alt_m)
    add(frame=FRAME_GLOBAL_RELATIVE_ALT_INT, command=CMD_TAKEOFF, z_m=alt_m)
    if speed_m_s is not None:
        add(frame=FRAME_MISSION, command=CMD_CHANGE_SPEED, param1=1.0, param2=speed_m_s,
            param3=-1.0)
    if roi is not None:
        add(frame=FRAME_GLOBAL_RELATIVE_ALT_INT, command=CMD_SET_ROI_LOCATION,
            lat_deg=roi.lat_deg, lon_deg=roi.lon_deg, z_m=roi.alt_m)
    for p in points:
        add(frame=FRAME_GLOBAL_RELATIVE_ALT_INT, command=CMD_WAYPOINT, param1=hold_s,
            param4=math.nan, lat_deg=p.lat_deg, lon_deg=p.lon_deg, z_m=p.alt_m)
    if roi is not None:
        add(frame=FRAME_MISSION, command=CMD_SET_ROI_NONE)
    add(frame=FRAME_MISSION, command=CMD_RTL)
    return items


def _geo(origin: GeoPoint, east: float, north: float, alt: float) -> GeoPoint:
    g = geo_from_enu(Enu(east_m=east, north_m=north), origin)
    return GeoPoint(lat_deg=g.lat_deg, lon_deg=g.lon_deg, alt_m=alt)


def survey(
    origin: GeoPoint, *, center_en_m: tuple[float, float] = (0.0, 0.0), width_m: float,
    height_m: float, spacing_m: float, alt_m: float, speed_m_s: float | None = 5.0,
    item0_is_home: bool = False,
) -> list[MissionItem]:
    """Lawnmower over a ``width_m`` (east) x ``height_m`` (north) box: north-south legs
    ``spacing_m`` apart (pick it from the camera footprint for full coverage)."""
    if width_m <= 0 or height_m <= 0 or spacing_m <= 0 or alt_m <= 0:
        raise PatternError("survey needs positive width, height, spacing and altitude")
    legs = max(1, math.ceil(width_m / spacing_m) + 1)
    step = width_m / (legs - 1) if legs > 1 else 0.0
    west = center_en_m[0] - width_m / 2
    south, north = center_en_m[1] - height_m / 2, center_en_m[1] + height_m / 2
    points: list[GeoPoint] = []
    for k in range(legs):
        east = west + k * step
        a, b = (south, north) if k % 2 == 0 else (north, south)
        points += [_geo(origin, east, a, alt_m), _geo(origin, east, b, alt_m)]
    return wrap_mission(points, home=origin, alt_m=alt_m, speed_m_s=speed_m_s,
                        item0_is_home=item0_is_home)


def orbit(
    origin: GeoPoint, *, center_en_m: tuple[float, float] = (0.0, 0.0), radius_m: float,
    alt_m: float, laps: float = 1.0, points_per_lap: int = 16, start_deg: float = 0.0,
    speed_m_s: float | None = 4.0, item0_is_home: bool = False,
) -> list[MissionItem]:
    """Waypoints on a circle around a point (the reconstruction target's multi-view pass),
    with the centre as region of interest: the nose stays on it, so a forward-tilted camera
    keeps it in view.

    ``start_deg`` (compass bearing from the centre) lets several drones share one orbit.
    """
    if radius_m <= 0 or alt_m <= 0 or laps <= 0 or points_per_lap < 3:
        raise PatternError("orbit needs positive radius, altitude, laps and >= 3 points/lap")
    n = max(3, round(laps * points_per_lap))
    points = []
    for k in range(n + 1):
        bearing = math.radians(start_deg + 360.0 * k / points_per_lap)
        points.append(_geo(origin, center_en_m[0] + radius_m * math.sin(bearing),
                           center_en_m[1] + radius_m * math.cos(bearing), alt_m))
    return wrap_mission(points, home=origin, alt_m=alt_m, speed_m_s=speed_m_s,
                        item0_is_home=item0_is_home, roi=_geo(origin, *center_en_m, 0.0))


def load_waypoints(path: Path, *, home: GeoPoint, default_alt_m: float,
                   item0_is_home: bool = False) -> list[MissionItem]:
    """Read a waypoint file: QGC WPL 110 (as MAVProxy/Mission Planner save) or CSV rows.

    CSV rows are ``lat,lon[,alt_rel_m[,hold_s]]``; ``#`` starts a comment. A QGC WPL file is
    taken as is (its item 0 is home, as in ArduPilot); for PX4 item 0 is dropped.
    """
    try:
        lines = Path(path).read_text().splitlines()
    except OSError as exc:
        raise PatternError(f"{path}: cannot read waypoint file ({exc.strerror})") from exc
    except UnicodeDecodeError as exc:
        raise PatternError(f"{path}: not a text file (byte {exc.start} is not UTF-8)") from None
    if lines and lines[0].startswith("QGC WPL"):
        items: list[MissionItem] = []
        for lineno, line in enumerate(lines[1:], start=2):
            f = line.split("\t") if "\t" in line else line.split()
            if not f:
                continue
            if len(f) != 12:
                raise PatternError(f"{path}:{lineno}: expected 12 fields, got {len(f)}")
            try:
                items.append(MissionItem(
                    seq=len(items), current=0, frame=int(f[2]), command=int(f[3]),
                    param1=float(f[4]), param2=float(f[5]), param3=float(f[6]),
                    param4=float(f[7]), lat_deg=float(f[8]), lon_deg=float(f[9]),
                    z_m=float(f[10]), autocontinue=int(f[11])))
            except ValueError as exc:
                raise PatternError(f"{path}:{lineno}: {exc}") from exc
        if not item0_is_home and items:
            items = [replace(it, seq=it.seq - 1) for it in items[1:]]
        return items
    points: list[GeoPoint] = []
    holds: set[float] = set()
    for lineno, raw in enumerate(lines, start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        parts = [p.strip() for p in line.split(",")]
        try:
            lat, lon = float(parts[0]), float(parts[1])
            alt = float(parts[2]) if len(parts) > 2 and parts[2] else default_alt_m
            holds.add(float(parts[3]) if len(parts) > 3 and parts[3] else 0.0)
            points.append(GeoPoint(lat_deg=lat, lon_deg=lon, alt_m=alt))
        except (ValueError, IndexError) as exc:
            raise PatternError(f"{path}:{lineno}: expected lat,lon[,alt[,hold_s]] ({exc})"
                               ) from exc
    if not points:
        raise PatternError(f"{path}: no waypoints")
    return wrap_mission(points, home=home, alt_m=points[0].alt_m, speed_m_s=None,
                        item0_is_home=item0_is_home, hold_s=max(holds))
