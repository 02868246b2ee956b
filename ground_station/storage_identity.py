"""A stored message is (sender, seq, t_gen), not (sender, seq).

A drone's companion counts ``seq`` from 0 again each time it starts (the wire decoder tells
its messages apart by ``t_gen``, docs/protocol.md). Keyed by (mission, sender, seq), the
station replaced an earlier run's image 2 (row and file) by the restarted run's image 2:
an operator lost a third of a drone's images to one companion restart. Here: the file name
of each image, so that no message takes another's, and the upgrade of a database keyed the
old way.
"""

from __future__ import annotations

import hashlib
import sqlite3
from collections.abc import Sequence
from pathlib import Path

from ground_station.storage_records import SCHEMA, StoreItem, safe_name
from utility_specs.message import Message

__all__ = ["generation_label", "image_relpath", "image_relpaths", "key_images_by_t_gen"]


def generation_label(t_gen: float) -> str:
    """``t_gen`` in a file name, to the microsecond (a hash for an absurd value)."""
    if abs(t_gen) < 1e12:
        return f"{t_gen:.6f}"
    return hashlib.sha256(repr(t_gen).encode()).hexdigest()[:16]


def image_relpath(mission: str, message: Message, *, renamed: bool = False) -> Path:
    """``missions/M/images/D/000000007-v1.jpg``: image 7, version 1. ``renamed``: another
    message of the drone's (an earlier run's) holds that name, so this one adds its t_gen:
    ``000000007~1796348405.119000-v1.jpg``."""
    version = "" if message.version is None else f"-v{message.version}"
    again = f"~{generation_label(message.t_gen)}" if renamed else ""
    return (Path("missions") / safe_name(mission) / "images" / safe_name(message.sender)
            / f"{message.seq:09d}{again}{version}.jpg")


def image_relpaths(db: sqlite3.Connection, items: Sequence[StoreItem]) -> list[Path | None]:
    """Each image's file (None for other messages). The message that first held a seq keeps
    the plain name; every other one with that sender and seq in the mission gets its own."""
    owners: dict[tuple[str, str, int], float | None] = {}
    out: list[Path | None] = []
    for item in items:
        m = item.message
        if item.payload is None:
            out.append(None)
            continue
        slot = (item.mission, m.sender, m.seq)
        if slot not in owners:
            try:
                owners[slot] = _plain_name_owner(db, slot, m.t_gen)
            except sqlite3.Error:  # cannot tell who holds the plain name: never take it
                owners[slot] = None
        out.append(image_relpath(item.mission, m, renamed=owners[slot] != m.t_gen))
    return out


def _plain_name_owner(db: sqlite3.Connection, slot: tuple[str, str, int], t_gen: float) -> float:
    """The t_gen of the stored image holding ``slot``'s plain file name, else ``t_gen``."""
    plain = f"{slot[2]:09d}"
    rows = db.execute(
        "SELECT t_gen, path FROM images WHERE mission = ? AND sender = ? AND seq = ?", slot)
    for row_t_gen, path in rows:
        stem = Path(path).stem if path else ""
        if stem == plain or stem.startswith(plain + "-v"):
            return float(row_t_gen)
    return t_gen


def key_images_by_t_gen(db: sqlite3.Connection) -> bool:
    """Move the images of a database keyed by (mission, sender, seq) to the table keyed by
    (mission, sender, seq, t_gen), in one transaction. True if it did."""
    (sql,) = db.execute(
        "SELECT sql FROM sqlite_master WHERE type = 'table' AND name = 'images'").fetchone()
    if "UNIQUE (mission, sender, seq)" not in sql:
        return False
    columns = ", ".join(r[1] for r in db.execute("PRAGMA table_info(images)"))
    try:
        db.executescript(
            "BEGIN; DROP INDEX IF EXISTS images_by_sender; DROP INDEX IF EXISTS images_by_utility;"
            f" ALTER TABLE images RENAME TO images_by_seq; {SCHEMA}"
            f" INSERT INTO images ({columns}) SELECT {columns} FROM images_by_seq;"
            " DROP TABLE images_by_seq; COMMIT;")
    except sqlite3.Error:
        if db.in_transaction:
            db.execute("ROLLBACK")
        raise
    return True
