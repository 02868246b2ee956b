"""Read-only queries on a ground station's database, for tools outside the station.

``uav-sitl fleet`` reads what a run stored while (or after) the station writes it: the
database is opened with a ``mode=ro`` URI, so a reader can neither change the station's
data nor create an empty database where none is. The schema is :mod:`ground_station.storage`'s.
"""

from __future__ import annotations

import sqlite3
from dataclasses import dataclass
from pathlib import Path

__all__ = ["StoredImages", "open_readonly", "stored_images"]


def open_readonly(db_path: Path, *, timeout_s: float = 10.0) -> sqlite3.Connection:
    """A connection that cannot write (``mode=ro``): raises sqlite3.Error when it is absent."""
    return sqlite3.connect(f"file:{db_path}?mode=ro", uri=True, timeout=timeout_s)


@dataclass(slots=True)
class StoredImages:
    """One sender's image rows of a mission."""

    rows: int = 0
    in_window: int = 0
    """Rows generated in the asked window [t_start, t_end]."""
    files: int = 0
    """Rows whose image file is on disk."""


def stored_images(db_path: Path, mission: str, *, t_start: float, t_end: float
                  ) -> dict[str, StoredImages]:
    """Per sender: the mission's image rows, those generated in [t_start, t_end], and those
    with their file on disk (paths are relative to the data folder, or absolute). No
    database yet: nothing stored."""
    out: dict[str, StoredImages] = {}
    if not db_path.exists():
        return out
    con = open_readonly(db_path)
    try:
        # type = 'image': the station also files telemetry payloads in this table.
        rows = con.execute(
            "SELECT sender, path, t_gen FROM images WHERE mission = ? AND type = 'image'",
            (mission,))
        for sender, path, t_gen in rows:
            entry = out.setdefault(sender, StoredImages())
            entry.rows += 1
            entry.in_window += t_start <= t_gen <= t_end
            if path and (db_path.parent / path).is_file():
                entry.files += 1
    finally:
        con.close()
    return out
