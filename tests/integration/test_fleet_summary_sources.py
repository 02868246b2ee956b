"""Where the fleet summary reads from: mission logs through ``utility_specs.log`` (decisions
kept, a torn last line skipped) and the station's database through the read-only
``ground_station.storage_queries``; and the probe's report through the middleware's one
report-to-link-sample path."""

from __future__ import annotations

import json
import math
import sqlite3
from pathlib import Path

import pytest

from companion.middleware.constraints.linkstats import LinkSample, RoundTrip
from companion.middleware.reports import link_observations
from ground_station.storage import SCHEMA
from ground_station.storage_queries import StoredImages, open_readonly, stored_images
from sitl.fleet import make_plan, parse_args, summarize
from sitl.fleet_config import write_run_configs
from sitl.linkemu.probe import PROBE, probe_report
from utility_specs.log import parse_log

T0 = 1_700_000_000.0


def _image(sender: str, seq: int, t_gen: float, *, rcv: float | None = None,
           reason: str | None = None) -> dict[str, object]:
    record: dict[str, object] = {
        "sender": sender, "receiver": "gs" if rcv else None, "seq": seq, "type": "image",
        "t_gen": t_gen, "t_sent": t_gen + 0.01, "t_rcv": rcv, "size": 1000,
        "data": {"red": 0.0}}
    if reason is not None:
        record["decision"] = {"send": True, "reason": reason}
    return record


def _database(db_path: Path, rows: list[tuple[str, int, float, str | None]]) -> None:
    """The station's own schema, with image rows (sender, seq, t_gen, path)."""
    db_path.parent.mkdir(parents=True, exist_ok=True)
    con = sqlite3.connect(db_path)
    con.executescript(SCHEMA)
    con.executemany(
        "INSERT INTO images (mission, sender, seq, type, t_gen, t_rcv, size, utility, path)"
        " VALUES ('fleet', ?, ?, 'image', ?, ?, 1000, 1.0, ?)",
        [(s, q, t, t + 0.1, p) for s, q, t, p in rows])
    con.execute("INSERT INTO images (mission, sender, seq, type, t_gen, t_rcv, size, utility)"
                " VALUES ('fleet', 'drone1', 99, 'telemetry', ?, ?, 10, 0.0)", (T0, T0))
    con.execute("INSERT INTO images (mission, sender, seq, type, t_gen, t_rcv, size, utility)"
                " VALUES ('other', 'drone1', 1, 'image', ?, ?, 10, 0.0)", (T0, T0))
    con.commit()
    con.close()


def test_stored_images_counts_rows_window_and_files_without_writing(tmp_path: Path) -> None:
    db_path = tmp_path / "gs" / "ground_station.sqlite3"
    assert stored_images(db_path, "fleet", t_start=T0, t_end=T0 + 10) == {}
    assert not db_path.exists()  # a reader never creates the station's database
    (tmp_path / "gs" / "img").mkdir(parents=True)
    (tmp_path / "gs" / "img" / "a.jpg").write_bytes(b"x")
    _database(db_path, [("drone1", 1, T0 - 1, "img/a.jpg"), ("drone1", 2, T0 + 1, "img/gone.jpg"),
                        ("drone2", 1, T0 + 11, None)])
    got = stored_images(db_path, "fleet", t_start=T0, t_end=T0 + 10)
    assert got == {"drone1": StoredImages(rows=2, in_window=1, files=1),
                   "drone2": StoredImages(rows=1, in_window=0, files=0)}
    con = open_readonly(db_path)
    with pytest.raises(sqlite3.OperationalError, match="readonly"):
        con.execute("DELETE FROM images")
    con.close()


def test_parse_log_keeps_asked_extras_by_message_index() -> None:
    lines = [json.dumps(_image("d", 0, 1.0)) + "\n",
             json.dumps({"mission": {"t_start": 0.0}}) + "\n",
             json.dumps(_image("d", 1, 2.0, reason="fallback: timeout")) + "\n"]
    log = parse_log(lines, keep=("decision",))
    assert log.extras == {1: {"decision": {"send": True, "reason": "fallback: timeout"}}}
    assert parse_log(lines).extras == {}


def test_summary_counts_decisions_stored_rows_and_skips_a_torn_line(tmp_path: Path) -> None:
    args = parse_args(["--drones", "1", "--goodput", "12000"])
    plan = make_plan(args, tmp_path / "run")
    write_run_configs(plan)
    log = plan.drones[0].log_path
    log.parent.mkdir(parents=True, exist_ok=True)
    reasons = ["mcts", "fallback: no time", "decision timeout", None, "mcts"]
    log.write_text("".join(json.dumps(_image("drone1", i, T0 + i, reason=r)) + "\n"
                           for i, r in enumerate(reasons)) + '{"sender": "drone1", "se')
    plan.gs_log_path.parent.mkdir(parents=True, exist_ok=True)
    plan.gs_log_path.write_text(json.dumps(_image("drone1", 0, T0, rcv=T0 + 0.2)) + "\n")
    _database(plan.gs_db_path, [("drone1", 0, T0, None), ("drone1", 1, T0 + 1, None)])
    s = summarize(plan, t_start=T0, t_end=T0 + 10, policy="mcts")
    d = s["drones"]["drone1"]
    assert (d["generated"], d["received"], d["stored"], d["stored_total"]) == (5, 1, 2, 2)
    assert d["decisions"] == 4 and d["fallback_share"] == 0.5
    assert d["latency_mean_s"] == pytest.approx(0.2)


def test_probe_report_feeds_the_samples_and_round_trip_it_always_did() -> None:
    payload = json.dumps({"t_report": 10.5, "arrivals": [[3, 10.0, 10.2, 1200],
                                                         [4, 10.1, 10.3, 1200]]}).encode()
    report = probe_report(payload, now=10.7)
    samples, trips, bad = link_observations(report, agent=PROBE)
    assert samples == [LinkSample(t_sent=10.0, t_rcv=10.2, size=1200, sender="probe", seq=3),
                       LinkSample(t_sent=10.1, t_rcv=10.3, size=1200, sender="probe", seq=4)]
    assert trips == [RoundTrip(t_sent=10.1, t_remote_rcv=10.3, t_remote_sent=10.5, t_rcv=10.7)]
    assert bad == 0
    empty = probe_report(b'{"t_report": 1.0, "arrivals": []}', now=1.1)
    assert link_observations(empty, agent=PROBE) == ([], [], 0)


@pytest.mark.parametrize("payload", [
    b"not json", b'{"arrivals": []}', b'{"t_report": 1, "arrivals": [[1, 2]]}',
    json.dumps({"t_report": 1.0, "arrivals": [[1, 0.5, math.inf, 10]]}).encode(),
])
def test_a_malformed_probe_report_is_refused_whole(payload: bytes) -> None:
    with pytest.raises((ValueError, KeyError, TypeError)):
        probe_report(payload, now=2.0)
