"""Geotags are true or absent: no 0/0, the pose age stored, stale poses out of geotags.csv."""

from __future__ import annotations

import csv
import sqlite3
from pathlib import Path
from typing import Any

from ground_station.export import export_mission
from ground_station.storage import POSE_STALE_AFTER_S, Storage, StoreItem, pose_quality
from utility_specs.message import Message

T0 = 1_700_000_000.0


def _image(seq: int, **geo: Any) -> StoreItem:
    m = Message(sender="d1", seq=seq, type="image", t_gen=T0 + seq, t_sent=T0 + seq,
                t_rcv=T0 + seq + 0.2, size=100, receiver="gs",
                data={"red": 0.0, "object": False, "roll_rad": 0.1, **geo})
    return StoreItem(mission="m", message=m, payload=bytes([seq]) * 100, utility=1.0)


FRESH = {"lat_deg": 51.0, "lon_deg": 17.0, "alt_rel_m": 30.0, "pose_age_s": 0.15}
STALE = {"lat_deg": 51.0, "lon_deg": 17.0, "alt_rel_m": 30.0, "pose_age_s": 9.5}
NONE = {"position": "none"}
NULL_ISLAND = {"lat_deg": 0.0, "lon_deg": 0.0, "alt_rel_m": 0.0}  # an older companion's


def test_pose_quality() -> None:
    assert POSE_STALE_AFTER_S == 1.0
    assert pose_quality(FRESH) == (0.15, "ok")
    assert pose_quality(STALE) == (9.5, "stale")
    assert pose_quality(NONE) == (None, "none")
    assert pose_quality(NULL_ISLAND) == (None, "none")
    assert pose_quality({"lat": 51.0, "lon": 17.0}) == (None, "ok")  # age not reported


def test_the_index_stores_pose_age_and_quality_and_never_0_0(tmp_path: Path) -> None:
    s = Storage(tmp_path)
    s.write_batch([_image(1, **FRESH), _image(2, **STALE), _image(3, **NONE),
                   _image(4, **NULL_ISLAND)], now=T0)
    rows = {r.seq: r for r in s.iter_images("m")}
    s.close()
    got = {seq: (r.lat_deg, r.lon_deg, r.alt_m, r.pose_age_s, r.pose) for seq, r in rows.items()}
    assert got == {1: (51.0, 17.0, 30.0, 0.15, "ok"), 2: (51.0, 17.0, 30.0, 9.5, "stale"),
                   3: (None, None, None, None, "none"), 4: (None, None, None, None, "none")}
    assert rows[3].as_json()["pose"] == "none"


def test_export_leaves_stale_and_missing_poses_out_unless_asked(tmp_path: Path) -> None:
    s = Storage(tmp_path / "data")
    s.write_batch([_image(1, **FRESH), _image(2, **STALE), _image(3, **NONE)], now=T0)
    s.close()
    result = export_mission(tmp_path / "data", "m", tmp_path / "out")
    assert (result.images, result.untagged) == (3, 2)
    assert sorted(p.name for p in (tmp_path / "out" / "images").iterdir()) == [
        "d1_000000001.jpg", "d1_000000002.jpg", "d1_000000003.jpg"]
    with open(result.csv_path, newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert [(r["image"], r["latitude"], r["pose_age_s"], r["pose"]) for r in rows] == [
        ("images/d1_000000001.jpg", "51.0", "0.15", "ok")]
    result = export_mission(tmp_path / "data", "m", tmp_path / "all", include_stale=True)
    with open(result.csv_path, newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert [(r["latitude"], r["pose"]) for r in rows] == [("51.0", "ok"), ("51.0", "stale"),
                                                         ("", "none")]


def test_a_database_of_an_older_version_gains_the_columns(tmp_path: Path) -> None:
    db = sqlite3.connect(tmp_path / "ground_station.sqlite3")
    db.execute("CREATE TABLE images (id INTEGER PRIMARY KEY, mission TEXT NOT NULL,"
               " sender TEXT NOT NULL, seq INTEGER NOT NULL, type TEXT NOT NULL,"
               " t_gen REAL NOT NULL, t_rcv REAL NOT NULL, size INTEGER NOT NULL,"
               " version INTEGER, red REAL, object INTEGER NOT NULL DEFAULT 0,"
               " utility REAL NOT NULL, lat_deg REAL, lon_deg REAL, alt_m REAL, x_m REAL,"
               " y_m REAL, roll_deg REAL, pitch_deg REAL, yaw_deg REAL, path TEXT, error TEXT,"
               " UNIQUE (mission, sender, seq))")
    db.execute("INSERT INTO images (mission, sender, seq, type, t_gen, t_rcv, size, utility,"
               " lat_deg, lon_deg, path) VALUES ('m', 'd1', 0, 'image', 1, 2, 3, 1.0, 51, 17,"
               " 'x.jpg')")
    db.commit()
    db.close()
    s = Storage(tmp_path)
    s.write_batch([_image(1, **STALE)], now=T0)
    rows = [(r.seq, r.pose) for r in s.iter_images("m")]
    s.close()
    assert rows == [(0, None), (1, "stale")]
