"""What the ground station stores, independent of how: the SQLite schema, the records
passed to and returned by :class:`~ground_station.storage.Storage`, and the pure helpers
that turn a received message into a row (geotag numbers, pose quality, JSON-safe data).

Split from :mod:`ground_station.storage` (issue 14) so the writer reads as file and
transaction handling only.
"""

from __future__ import annotations

import hashlib
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from utility_specs.log import message_to_record
from utility_specs.message import Message

__all__ = [
    "NEW_IMAGE_COLUMNS",
    "POSE_STALE_AFTER_S",
    "SCHEMA",
    "BatchResult",
    "ImageRow",
    "StoreItem",
    "angle_deg",
    "geo_number",
    "jsonable",
    "log_record",
    "pose_quality",
    "safe_name",
]

SCHEMA = """
CREATE TABLE IF NOT EXISTS missions (
    name TEXT PRIMARY KEY,
    t_created REAL NOT NULL,
    t_start REAL,
    t_end REAL
);
CREATE TABLE IF NOT EXISTS mission_bounds (
    mission TEXT NOT NULL,
    t_start REAL,
    t_end REAL,
    kind TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS mission_bounds_by_mission ON mission_bounds (mission);
CREATE TABLE IF NOT EXISTS messages (
    id INTEGER PRIMARY KEY,
    mission TEXT NOT NULL,
    sender TEXT NOT NULL,
    seq INTEGER NOT NULL,
    type TEXT NOT NULL,
    t_gen REAL NOT NULL,
    t_sent REAL,
    t_rcv REAL NOT NULL,
    size INTEGER NOT NULL,
    version INTEGER,
    data TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS messages_by_sender ON messages (mission, sender, t_rcv);
CREATE TABLE IF NOT EXISTS images (
    id INTEGER PRIMARY KEY,
    mission TEXT NOT NULL,
    sender TEXT NOT NULL,
    seq INTEGER NOT NULL,
    type TEXT NOT NULL,
    t_gen REAL NOT NULL,
    t_rcv REAL NOT NULL,
    size INTEGER NOT NULL,
    version INTEGER,
    red REAL,
    object INTEGER NOT NULL DEFAULT 0,
    utility REAL NOT NULL,
    lat_deg REAL, lon_deg REAL, alt_m REAL,
    x_m REAL, y_m REAL,
    roll_deg REAL, pitch_deg REAL, yaw_deg REAL,
    path TEXT,
    error TEXT,
    pose_age_s REAL,
    pose TEXT,
    alt_amsl_m REAL,
    UNIQUE (mission, sender, seq, t_gen)
);
CREATE INDEX IF NOT EXISTS images_by_sender ON images (mission, sender, t_rcv);
CREATE INDEX IF NOT EXISTS images_by_utility ON images (mission, utility);
CREATE TABLE IF NOT EXISTS alerts (
    id INTEGER PRIMARY KEY,
    mission TEXT NOT NULL,
    t REAL NOT NULL,
    level TEXT NOT NULL,
    kind TEXT NOT NULL,
    drone TEXT,
    text TEXT NOT NULL
);
"""

_SAFE = re.compile(r"[^A-Za-z0-9_.-]")


def safe_name(name: str) -> str:
    """A sender or mission id usable as one path component, one per id.

    An id of letters, digits and ``_.-`` (up to 64) is its own name. Any other gets what is
    left of it after cleaning plus ``~`` and a hash of the id: replacing characters alone
    mapped ``Möwe1`` and ``Mäwe1`` (or ``uav 1`` and ``uav_1``) to one folder, where the
    second drone's images overwrote the first's files under the first's database rows (the
    dashboard showed one drone's picture as the other's). ``~`` is never in a clean name,
    so a cleaned one cannot meet a clean one either."""
    cleaned = _SAFE.sub("_", name)
    if cleaned == name and len(name) <= 64 and name not in ("", ".", ".."):
        return name
    digest = hashlib.sha256(name.encode("utf-8", "surrogatepass")).hexdigest()[:12]
    return f"{cleaned[:51]}~{digest}"


def jsonable(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, Mapping):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if isinstance(value, str | int | float | bool) or value is None:
        return value
    return str(value)


def log_record(message: Message) -> dict[str, Any]:
    """One mission-log line (the JSON Lines contract read by ``uav-utility evaluate``)."""
    record = message_to_record(message)
    record["data"] = jsonable(record["data"])
    return record


@dataclass(frozen=True, slots=True, kw_only=True)
class StoreItem:
    """One received message to persist; ``payload`` is set for images."""

    mission: str
    message: Message
    payload: bytes | None = None
    utility: float | None = None
    """Image utility weight (eq. 7.1/7.2); only for images."""
    t_rcv: float | None = None
    """The link's reception time, unclamped (for the receiver report's entry)."""


@dataclass(slots=True, kw_only=True)
class BatchResult:
    image_ids: list[int | None] = field(default_factory=list)
    """Per item, the images.id row (None for telemetry or when the row failed)."""
    errors: list[str] = field(default_factory=list)
    """Human-readable storage errors (e.g. disk full) raised while writing this batch."""
    images_stored: int = 0
    """Image files that reached the disk."""
    stored: list[bool] = field(default_factory=list)
    """Per item, True when it is durable: its row committed and, for an image, its file
    written under its final name. Only these may be reported delivered."""


@dataclass(frozen=True, slots=True, kw_only=True)
class ImageRow:
    id: int
    mission: str
    sender: str
    seq: int
    type: str
    t_gen: float
    t_rcv: float
    size: int
    version: int | None
    red: float | None
    object: bool
    utility: float
    lat_deg: float | None
    lon_deg: float | None
    alt_m: float | None
    x_m: float | None
    y_m: float | None
    roll_deg: float | None
    pitch_deg: float | None
    yaw_deg: float | None
    path: str | None
    error: str | None
    pose_age_s: float | None = None
    """How old the position was when the image was taken (None: not reported)."""
    pose: str | None = None
    """``ok``, ``stale`` (older than POSE_STALE_AFTER_S) or ``none`` (no fix: no position)."""
    alt_amsl_m: float | None = None
    """Altitude above mean sea level at capture (``alt_m`` is above home); None: not sent."""

    def as_json(self) -> dict[str, Any]:
        return {name: getattr(self, name) for name in self.__dataclass_fields__}


POSE_STALE_AFTER_S = 1.0
"""An image's position older than this (5 samples at the companion's 5 Hz) is stale: an
autopilot outage, not the geotag of the place the image shows."""
NEW_IMAGE_COLUMNS = (("pose_age_s", "REAL"), ("pose", "TEXT"), ("alt_amsl_m", "REAL"))


def pose_quality(data: Mapping[str, Any]) -> tuple[float | None, str]:
    """(pose age, ``ok``/``stale``/``none``) of an image's geotag data."""
    age = geo_number(data, "pose_age_s")
    lat, lon = geo_number(data, "lat_deg", "lat"), geo_number(data, "lon_deg", "lon")
    if data.get("position") == "none" or lat is None or lon is None \
            or (abs(lat) < 1e-6 and abs(lon) < 1e-6) or not (abs(lat) <= 90 and abs(lon) <= 180):
        return age, "none"  # no position, 0/0 (no origin), or not a place on Earth
    if age is not None and age > POSE_STALE_AFTER_S:
        return age, "stale"
    return age, "ok"


def geo_number(data: Mapping[str, Any], *keys: str) -> float | None:
    for key in keys:
        value = data.get(key)
        if isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value):
            return float(value)
    return None


def angle_deg(data: Mapping[str, Any], *keys: str, radians: str) -> float | None:
    """An attitude angle in degrees; the companion's geotags carry MAVLink's radians."""
    value = geo_number(data, *keys)
    if value is not None:
        return value
    rad = geo_number(data, radians)
    return math.degrees(rad) if rad is not None else None
