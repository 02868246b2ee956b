"""Geodetic <-> local ENU/NED conversions on the WGS84 ellipsoid.

The simulator thinks in a local tangent plane around the scene's home point (east, north, up
metres); MAVLink speaks latitude/longitude/altitude. The conversion goes through ECEF, so it
is exact (to floating point) at any distance, not a flat-earth approximation. Shared by the
simulator and the scene file format (:mod:`utility_specs.scene`): the bottom layer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["WGS84_A_M", "WGS84_F", "Enu", "GeoPoint", "enu_from_geo", "geo_from_enu"]

WGS84_A_M = 6_378_137.0
WGS84_F = 1.0 / 298.257223563
_E2 = WGS84_F * (2.0 - WGS84_F)
_B_M = WGS84_A_M * (1.0 - WGS84_F)
_EP2 = (WGS84_A_M**2 - _B_M**2) / _B_M**2


@dataclass(frozen=True, slots=True, kw_only=True)
class GeoPoint:
    """A geodetic position: latitude/longitude in degrees, altitude above the ellipsoid in m."""

    lat_deg: float
    lon_deg: float
    alt_m: float = 0.0

    def __post_init__(self) -> None:
        if not -90.0 <= self.lat_deg <= 90.0:
            raise ValueError(f"lat_deg must be in [-90, 90], got {self.lat_deg}")
        if not -180.0 <= self.lon_deg <= 180.0:
            raise ValueError(f"lon_deg must be in [-180, 180], got {self.lon_deg}")
        if not math.isfinite(self.alt_m):
            raise ValueError(f"alt_m must be finite, got {self.alt_m}")


@dataclass(frozen=True, slots=True, kw_only=True)
class Enu:
    """A local position in metres: east, north, up from an origin."""

    east_m: float
    north_m: float
    up_m: float = 0.0


def _ecef(p: GeoPoint) -> tuple[float, float, float]:
    lat, lon = math.radians(p.lat_deg), math.radians(p.lon_deg)
    n = WGS84_A_M / math.sqrt(1.0 - _E2 * math.sin(lat) ** 2)
    x = (n + p.alt_m) * math.cos(lat) * math.cos(lon)
    y = (n + p.alt_m) * math.cos(lat) * math.sin(lon)
    z = (n * (1.0 - _E2) + p.alt_m) * math.sin(lat)
    return x, y, z


def _geo(x: float, y: float, z: float) -> GeoPoint:
    """ECEF -> geodetic by Bowring's start and three Newton-like refinements (sub-mm)."""
    lon = math.atan2(y, x)
    p = math.hypot(x, y)
    theta = math.atan2(z * WGS84_A_M, p * _B_M)
    lat = math.atan2(
        z + _EP2 * _B_M * math.sin(theta) ** 3, p - _E2 * WGS84_A_M * math.cos(theta) ** 3
    )
    for _ in range(3):
        n = WGS84_A_M / math.sqrt(1.0 - _E2 * math.sin(lat) ** 2)
        alt = p / math.cos(lat) - n if abs(math.cos(lat)) > 1e-09 else abs(z) - _B_M
        lat = math.atan2(z, p * (1.0 - _E2 * n / (n + alt)))
    n = WGS84_A_M / math.sqrt(1.0 - _E2 * math.sin(lat) ** 2)
    alt = p / math.cos(lat) - n if abs(math.cos(lat)) > 1e-9 else abs(z) - _B_M
    return GeoPoint(lat_deg=math.degrees(lat), lon_deg=math.degrees(lon), alt_m=alt)


def enu_from_geo(point: GeoPoint, origin: GeoPoint) -> Enu:
    """Local east/north/up of ``point`` seen from ``origin`` (metres)."""
    x, y, z = _ecef(point)
    x0, y0, z0 = _ecef(origin)
    dx, dy, dz = x - x0, y - y0, z - z0
    lat, lon = math.radians(origin.lat_deg), math.radians(origin.lon_deg)
    sl, cl, sp, cp = math.sin(lon), math.cos(lon), math.sin(lat), math.cos(lat)
    east = -sl * dx + cl * dy
    north = -sp * cl * dx - sp * sl * dy + cp * dz
    up = cp * cl * dx + cp * sl * dy + sp * dz
    return Enu(east_m=east, north_m=north, up_m=up)


def geo_from_enu(local: Enu, origin: GeoPoint) -> GeoPoint:
    """Geodetic position of the local point ``local`` around ``origin``."""
    lat, lon = math.radians(origin.lat_deg), math.radians(origin.lon_deg)
    sl, cl, sp, cp = math.sin(lon), math.cos(lon), math.sin(lat), math.cos(lat)
    e, n, u = local.east_m, local.north_m, local.up_m
    dx = -sl * e - sp * cl * n + cp * cl * u
    dy = cl * e - sp * sl * n + cp * sl * u
    dz = cp * n + sp * u
    x0, y0, z0 = _ecef(origin)
    return _geo(x0 + dx, y0 + dy, z0 + dz)
