"""A restarted companion counts seq from 0 again: nothing its earlier run sent is lost.

Found flying two drones against a real station: after one ``kill -TERM`` and restart of a
companion, its new image 2 replaced the stored image 2 of the first run (row and file), so
74 of 115 earlier images were left, the station's counters disagreed with its own gallery,
and ``uav-utility evaluate`` took the two runs' messages of one seq for copies of one
message (14 % of the utility missing). A message is (sender, seq, t_gen), as on the wire.
"""

from __future__ import annotations

import csv
import sqlite3
from dataclasses import replace
from pathlib import Path

from companion.middleware.knowledge import FleetKnowledge
from ground_station.export import export_mission
from ground_station.storage import Storage, StoreItem
from ground_station.storage_records import SCHEMA
from tests.ground_station.test_gs_storage import T0, image
from tests.middleware.conftest import VERSIONS
from utility_specs.evaluate import evaluate
from utility_specs.files import builtin_spec
from utility_specs.message import Message

RESTART_S = 600.0


def again(item: StoreItem, *, payload: bytes = b"second run") -> StoreItem:
    """The same seq from the companion's next run: later t_gen, other bytes."""
    m = item.message
    later = replace(m, t_gen=m.t_gen + RESTART_S, t_sent=m.t_gen + RESTART_S,
                    t_rcv=(m.t_rcv or m.t_gen) + RESTART_S)
    return replace(item, message=later, payload=payload)


def test_a_restarted_drones_images_keep_the_earlier_runs(tmp_path: Path) -> None:
    s = Storage(tmp_path, fsync=False)
    first = [image(1), image(2)]
    s.write_batch(first, now=T0)
    result = s.write_batch([again(image(1)), again(image(2))], now=T0 + RESTART_S)
    assert result.stored == [True, True]
    rows = sorted(s.images("m", limit=10), key=lambda r: (r.seq, r.t_gen))
    assert [(r.seq, r.t_gen) for r in rows] == [
        (1, T0 + 1), (1, T0 + 1 + RESTART_S), (2, T0 + 2), (2, T0 + 2 + RESTART_S)]
    paths = [Path(r.path) for r in rows if r.path]
    assert len(set(paths)) == 4
    assert (tmp_path / paths[0]).read_bytes() == first[0].payload  # untouched
    assert paths[0].name == "000000001.jpg"
    assert paths[1].name == f"000000001~{T0 + 1 + RESTART_S:.6f}.jpg"
    assert (tmp_path / paths[1]).read_bytes() == b"second run"
    assert s.counts("m")["images"] == 4 and s.counts("m")["images_on_disk"] == 4
    s.close()


def test_both_runs_in_one_batch_and_a_later_version_of_either(tmp_path: Path) -> None:
    s = Storage(tmp_path, fsync=False)
    old, new = image(3), again(image(3))
    s.write_batch([old, new], now=T0)
    # a better version of the restarted run's message replaces only that message's row
    better = replace(new, message=replace(new.message, versions=VERSIONS, version=1),
                     payload=b"v1")
    s.write_batch([better], now=T0 + RESTART_S)
    rows = sorted(s.images("m", limit=10), key=lambda r: r.t_gen)
    assert [(r.t_gen, r.version) for r in rows] == [(T0 + 3, None), (T0 + 3 + RESTART_S, 1)]
    assert Path(rows[0].path or "").name == "000000003.jpg"
    assert Path(rows[1].path or "").name == f"000000003~{T0 + 3 + RESTART_S:.6f}-v1.jpg"
    s.close()


def test_a_database_keyed_by_seq_is_upgraded_without_losing_a_row(tmp_path: Path) -> None:
    old_schema = SCHEMA.replace("UNIQUE (mission, sender, seq, t_gen)",
                                "UNIQUE (mission, sender, seq)")
    assert old_schema != SCHEMA
    db = sqlite3.connect(tmp_path / "ground_station.sqlite3")
    db.executescript(old_schema)
    db.execute("INSERT INTO images (mission, sender, seq, type, t_gen, t_rcv, size, utility,"
               " path) VALUES ('m', 'd1', 1, 'image', ?, ?, 10, 1.0, ?)",
               (T0 + 1, T0 + 1.2, "missions/m/images/d1/000000001.jpg"))
    db.commit()
    db.close()
    s = Storage(tmp_path, fsync=False)
    (sql,) = s.db.execute("SELECT sql FROM sqlite_master WHERE name = 'images'").fetchone()
    assert "UNIQUE (mission, sender, seq, t_gen)" in sql
    indexes = {r[1] for r in s.db.execute("PRAGMA index_list(images)")}
    assert {"images_by_sender", "images_by_utility"} <= indexes
    s.write_batch([again(image(1))], now=T0 + RESTART_S)
    assert sorted(r.t_gen for r in s.images("m", limit=10)) == [T0 + 1, T0 + 1 + RESTART_S]
    s.close()
    Storage(tmp_path, fsync=False).close()  # a second open finds nothing to upgrade


def test_export_names_every_run_s_image(tmp_path: Path) -> None:
    s = Storage(tmp_path / "data", fsync=False)
    s.write_batch([image(1), again(image(1))], now=T0)
    s.close()
    result = export_mission(tmp_path / "data", "m", tmp_path / "out")
    assert result.images == 2
    with open(result.csv_path, newline="") as handle:
        names = [r["image"] for r in csv.DictReader(handle)]
    assert names == ["images/d1_000000001.jpg", f"images/d1_000000001~{T0 + 1 + RESTART_S:.6f}.jpg"]
    assert (tmp_path / "out" / names[1]).read_bytes() == b"second run"


def _battery(seq: int, t_gen: float) -> Message:
    return Message(sender="d1", seq=seq, type="battery", t_gen=t_gen, t_rcv=t_gen + 0.1,
                   receiver="gs", data={"level": 0.9})


def test_evaluate_counts_both_runs_messages_of_one_seq() -> None:
    spec = builtin_spec("image_streaming")
    runs = [_battery(0, 10.0), _battery(0, 110.0)]
    seqs_apart = [_battery(0, 10.0), _battery(1, 110.0)]
    as_copies = evaluate(runs[:1], spec, t_end=200.0).total
    total = evaluate(runs, spec, t_end=200.0).total
    assert total == evaluate(seqs_apart, spec, t_end=200.0).total
    assert total != as_copies


def test_a_restarted_peer_s_messages_are_news_to_the_fleet_knowledge() -> None:
    k = FleetKnowledge(builtin_spec("image_streaming"), agent="a", default_latency_s=0.05)
    assert k.on_delivered([_battery(0, 10.0)], now=10.2) == 1
    assert k.on_delivered([_battery(0, 10.0)], now=10.3) == 0  # a copy
    assert k.on_delivered([_battery(0, 110.0)], now=110.2) == 1  # its next run's first
