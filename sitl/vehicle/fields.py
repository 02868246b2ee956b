"""Checks on the fields of received MAVLink messages: bad values become :class:`BadField`.

The vehicle counts a well-formed frame whose values no autopilot could act on (NaN, out of
range) and answers with a STATUSTEXT, never an exception out of ``receive_datagram``.
"""

from __future__ import annotations

import math
from typing import Any

from sitl.vehicle.mission import GLOBAL_FRAMES, RELATIVE_FRAMES, is_nav_command


class BadField(ValueError):
    """A field of a received message that is NaN, infinite or out of range."""


def int_field(value: float, name: str) -> int:
    """An integer-valued command parameter; NaN/inf are bad input, not a crash."""
    if not math.isfinite(value) or abs(value) > 2**31:
        raise BadField(f"{name} must be a finite integer, got {value}")
    return int(value)


def finite_field(values: tuple[float, ...], name: str) -> tuple[float, ...]:
    if not all(math.isfinite(v) for v in values):
        raise BadField(f"{name} must be finite, got {values}")
    return values


def lat_lon_field(lat_deg: float, lon_deg: float) -> tuple[float, float]:
    if not (math.isfinite(lat_deg) and -90.0 <= lat_deg <= 90.0 and math.isfinite(lon_deg)
            and -180.0 <= lon_deg <= 180.0):
        raise BadField(f"latitude/longitude out of range: {lat_deg}, {lon_deg}")
    return lat_deg, lon_deg


def text_field(value: Any) -> str:
    if isinstance(value, bytes):
        value = value.decode("utf-8", "replace")
    return str(value).split("\x00", 1)[0]


def mission_item_error(msg: Any, scale: float) -> int | None:
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

