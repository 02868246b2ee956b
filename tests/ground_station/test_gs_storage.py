"""Storage: WAL index, atomic image files, mission log, full disk, export."""

from __future__ import annotations

import csv
import errno
import json
import os
from pathlib import Path

import pytest

from ground_station.export import export_mission
from ground_station.storage import Storage, StoreItem
from utility_specs.files import read_log
from utility_specs.message import Message

T0 = 1_700_000_000.0


def image(seq: int, *, sender: str = "d1", red: float = 0.0, obj: bool = False) -> StoreItem:
    m = Message(
        sender=sender,
        seq=seq,
        type="image",
        t_gen=T0 + seq,
        t_sent=T0 + seq,
        t_rcv=T0 + seq + 0.2,
        size=1000 + seq,
        receiver="gs",
        data={
            "red": red,
            "object": obj,
            "lat": 51.0 + seq / 1e4,
            "lon": 17.0,
            "alt": 40.0,
            "yaw_deg": 90.0,
            "pitch_deg": -2.0,
            "roll_deg": 1.0,
        },
    )
    return StoreItem(
        mission="m",
        message=m,
        payload=bytes([seq]) * (1000 + seq),
        utility=1 + 10 * red + (10 if obj else 0),
    )


def telemetry(seq: int) -> StoreItem:
    m = Message(
        sender="d1",
        seq=seq,
        type="battery",
        t_gen=T0 + seq,
        t_rcv=T0 + seq + 0.1,
        receiver="gs",
        data={"level": 0.5},
    )
    return StoreItem(mission="m", message=m)


def test_schema_wal_and_index(tmp_path: Path) -> None:
    s = Storage(tmp_path)
    assert s.db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    cols = [r[2] for r in s.db.execute("PRAGMA index_info(images_by_sender)")]
    assert cols == ["mission", "sender", "t_rcv"]
    plan = " ".join(
        str(r[3])
        for r in s.db.execute(
            "EXPLAIN QUERY PLAN SELECT * FROM images WHERE mission='m' AND sender='d1'"
            " AND t_rcv > 0"
        )
    )
    assert "images_by_sender" in plan
    s.close()


def test_batch_files_index_and_log(tmp_path: Path) -> None:
    s = Storage(tmp_path)
    result = s.write_batch([image(1, red=0.5), telemetry(2), image(3, obj=True)], now=T0)
    assert result.errors == [] and result.images_stored == 2
    assert result.image_ids[1] is None and None not in (result.image_ids[0], result.image_ids[2])
    rows = s.images("m")
    assert [r.seq for r in rows] == [3, 1]  # utility 11 before 6
    assert (tmp_path / rows[0].path).read_bytes() == bytes([3]) * 1003  # type: ignore[operator]
    assert rows[0].object is True and rows[1].red == 0.5 and rows[1].lat_deg == 51.0001
    assert [r.seq for r in s.images("m", object_only=False)] == [1]
    assert not list(tmp_path.rglob("*.tmp"))
    assert s.counts("m") == {"images": 2, "images_on_disk": 2, "messages": 3}
    s.mark_mission("m", now=T0, t_end=T0 + 10)
    s.close()
    log = read_log(Storage(tmp_path).log_path("m"))
    assert [(m.seq, m.type, m.receiver) for m in log.messages] == [
        (1, "image", "gs"),
        (2, "battery", "gs"),
        (3, "image", "gs"),
    ]
    assert log.messages[0].t_rcv == T0 + 1.2 and log.t_end == T0 + 10


def test_full_disk_is_reported_and_telemetry_still_stored(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    s = Storage(tmp_path)

    def full(self: Storage, relpath: Path, payload: bytes) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(Storage, "_write_file", full)
    result = s.write_batch([image(1), telemetry(2)], now=T0)
    assert result.images_stored == 0
    [error] = result.errors
    assert "image d1/1 not stored: disk full" in error and str(tmp_path) in error
    assert s.counts("m") == {"images": 1, "images_on_disk": 0, "messages": 2}
    assert s.images("m") == []  # the gallery only lists images that exist
    s.close()


def test_restart_reads_history(tmp_path: Path) -> None:
    s = Storage(tmp_path)
    s.write_batch([image(1, red=0.1), image(2, sender="d2", red=0.2), image(3, red=0.3)], now=T0)
    s.close()
    again = Storage(tmp_path)
    assert {(r.sender, r.seq) for r in again.latest_images("m")} == {("d1", 3), ("d2", 2)}
    assert [m["name"] for m in again.missions()] == ["m"]
    again.close()


def test_a_restart_removes_half_written_images_of_a_crash(tmp_path: Path) -> None:
    s = Storage(tmp_path)
    s.write_batch([image(1)], now=T0)
    s.close()
    [stored] = (tmp_path / "missions").rglob("*.jpg")
    torn = stored.with_name(f".{stored.name[:-4]}2.jpg.tmp")  # a crash between write and rename
    torn.write_bytes(b"\xff\xd8 half")
    again = Storage(tmp_path)
    assert again.removed_temp_files == 1 and not torn.exists() and stored.exists()
    again.close()
    torn.write_bytes(b"\xff\xd8 half")
    reader = Storage(tmp_path, readonly=True)  # a reader never deletes anything
    assert reader.removed_temp_files == 0 and torn.exists()
    reader.close()


def test_export_images_and_geotag_csv(tmp_path: Path) -> None:
    s = Storage(tmp_path / "data")
    s.write_batch([image(1), image(2, sender="d2", obj=True)], now=T0)
    s.close()
    result = export_mission(tmp_path / "data", "m", tmp_path / "out")
    assert result.images == 2 and result.missing == 0
    with open(result.csv_path, newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert [r["image"] for r in rows] == ["images/d1_000000001.jpg", "images/d2_000000002.jpg"]
    assert rows[1]["latitude"] == "51.0002" and rows[1]["yaw"] == "90.0"
    assert rows[1]["object"] == "1"
    assert (tmp_path / "out" / rows[0]["image"]).read_bytes() == bytes([1]) * 1001
    with pytest.raises(KeyError, match="not found"):
        export_mission(tmp_path / "data", "nope", tmp_path / "out2")


def test_log_record_is_json_with_versions(tmp_path: Path) -> None:
    s = Storage(tmp_path)
    s.write_batch([telemetry(5)], now=T0)
    s.close()
    lines = [json.loads(x) for x in Storage(tmp_path).log_path("m").read_text().splitlines()]
    # opened by its first message, closed at its last reception (the station's own bounds)
    assert lines[0] == {"mission": {"t_start": T0 + 5, "kind": "open"}}
    assert lines[-1] == {"mission": {"t_end": T0 + 5.1, "kind": "stop"}}
    line = lines[1]
    assert line == {
        "sender": "d1",
        "receiver": "gs",
        "seq": 5,
        "type": "battery",
        "t_gen": T0 + 5,
        "t_sent": None,
        "t_rcv": T0 + 5.1,
        "size": 0,
        "data": {"level": 0.5},
    }


def test_attitude_in_radians_is_stored_in_degrees(tmp_path: Path) -> None:
    """The companion's geotag has MAVLink's ``roll_rad``/``pitch_rad``/``yaw_rad``: before, the
    database and ``export`` left roll and pitch empty."""
    item = image(1)
    data = {k: v for k, v in item.message.data.items() if not k.endswith("_deg")}
    data.update(roll_rad=0.1, pitch_rad=-0.05, yaw_rad=1.5)
    message = Message(sender="d1", seq=1, type="image", t_gen=T0, t_sent=T0, t_rcv=T0 + 0.2,
                      size=1001, receiver="gs", data=data)
    s = Storage(tmp_path)
    s.write_batch([StoreItem(mission="m", message=message, payload=b"x" * 1001, utility=1.0)],
                  now=T0 + 1)
    roll, pitch, yaw = s.db.execute("SELECT roll_deg, pitch_deg, yaw_deg FROM images").fetchone()
    s.close()
    assert roll == pytest.approx(5.729577951308232)
    assert pitch == pytest.approx(-2.864788975654116)
    assert yaw == pytest.approx(85.94366926962348)
