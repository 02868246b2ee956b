"""Operator checks (audit 12): ``geotags.csv``'s ``altitude`` is the camera's altitude above
mean sea level when the drone sent it. The export wrote the height above home instead
(30.0 for every image of a demo flown at 30 m over a home at 488 m AMSL), which
photogrammetry reads as a GPS altitude: georeferenced elevations off by the home's."""

from __future__ import annotations

import csv
import sqlite3
from pathlib import Path

from ground_station.export import export_mission
from ground_station.storage import Storage, StoreItem
from utility_specs.message import Message

T0 = 1_700_000_000.0


def _image(seq: int, **geo: float) -> StoreItem:
    m = Message(sender="d1", seq=seq, type="image", t_gen=T0 + seq, t_sent=T0 + seq,
                t_rcv=T0 + seq + 0.2, size=100, receiver="gs",
                data={"red": 0.0, "lat_deg": 47.39, "lon_deg": 8.54, "pose_age_s": 0.1, **geo})
    return StoreItem(mission="m", message=m, payload=bytes([seq]) * 100, utility=1.0)


def _csv(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def test_altitude_is_above_sea_level_when_the_drone_sent_it(tmp_path: Path) -> None:
    s = Storage(tmp_path / "data")
    s.write_batch([_image(1, alt_rel_m=30.0, alt_amsl_m=518.0),  # the companion's geotag
                   _image(2, alt_rel_m=31.5)], now=T0)  # a drone that sends no AMSL
    rows = {r.seq: r for r in s.iter_images("m")}
    s.close()
    assert (rows[1].alt_m, rows[1].alt_amsl_m) == (30.0, 518.0)
    assert (rows[2].alt_m, rows[2].alt_amsl_m) == (31.5, None)
    result = export_mission(tmp_path / "data", "m", tmp_path / "out")
    got = [(r["altitude"], r["altitude_above_home"], r["altitude_ref"])
           for r in _csv(result.csv_path)]
    assert got == [("518.0", "30.0", "amsl"), ("31.5", "31.5", "home")]


def test_an_older_database_gains_the_column_and_exports_as_before(tmp_path: Path) -> None:
    s = Storage(tmp_path / "data")
    s.write_batch([_image(1, alt_rel_m=30.0)], now=T0)
    s.close()
    db = tmp_path / "data" / "ground_station.sqlite3"
    with sqlite3.connect(db) as conn:  # as an older version left it
        conn.execute("ALTER TABLE images DROP COLUMN alt_amsl_m")
    rows = _csv(export_mission(tmp_path / "data", "m", tmp_path / "old").csv_path)
    assert [(r["altitude"], r["altitude_ref"]) for r in rows] == [("30.0", "home")]
    s = Storage(tmp_path / "data")  # read-write: the column is added
    s.write_batch([_image(2, alt_rel_m=30.0, alt_amsl_m=518.0)], now=T0)
    s.close()
    rows = _csv(export_mission(tmp_path / "data", "m", tmp_path / "new").csv_path)
    assert [r["altitude"] for r in rows] == ["30.0", "518.0"]
