"""The simulator's geodesy: :mod:`utility_specs.geo`, re-exported under its old name.

Moved down a layer (issue 14) because the scene file format, which the ground station's map
reads too, holds a :class:`GeoPoint`.
"""

from utility_specs.geo import WGS84_A_M, WGS84_F, Enu, GeoPoint, enu_from_geo, geo_from_enu

__all__ = ["WGS84_A_M", "WGS84_F", "Enu", "GeoPoint", "enu_from_geo", "geo_from_enu"]
