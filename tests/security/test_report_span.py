"""The report's size is bounded whatever the mission's stored start (docs/security.md, 2026-11-24).

``utility_series`` cut the span from the mission's ``t_start`` to its last image into 5 s bins,
with no bound: a ``t_start`` in 1970 (the control API took any finite time until row 16)
made a read of ``GET /api/report`` build 3.6e8 bins per drone and a reply of gigabytes; a
start 30 days back was a 10 MB reply and 2 s of work on a real station. Here the span is
1e7 s (2e6 bins per drone before the fix: heavy enough to tell, light enough to run).
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ground_station.app import create_app
from ground_station.config import GroundConfig
from ground_station.report_page import BIN_S, MAX_BINS, utility_series
from ground_station.storage import Storage
from tests.keys import TEST_COMMAND_KEY

TOKEN = "report-span-token-0123456789"
T_IMAGES = 1_790_000_000.0
SPAN_S = 1e7


def _fill(root: Path, *, t_start: float) -> Path:
    storage = Storage(root, fsync=False)
    db = storage.db
    db.execute("INSERT INTO missions (name, t_created, t_start) VALUES ('m', 0, ?)", (t_start,))
    rows = [("uav1", T_IMAGES, 1.0), ("uav1", T_IMAGES + 2.0, 2.0), ("uav2", T_IMAGES + 9, 4.0)]
    for seq, (sender, t, u) in enumerate(rows):
        db.execute("INSERT INTO images (mission, sender, seq, type, t_gen, t_rcv, size, "
                   "utility) VALUES ('m', ?, ?, 'image', ?, ?, 100, ?)",
                   (sender, seq, t - 0.1, t, u))
    db.commit()
    path = storage.db_path
    db.close()
    return path


def test_a_start_long_before_the_images_widens_the_bins(tmp_path: Path) -> None:
    db = sqlite3.connect(_fill(tmp_path, t_start=T_IMAGES - SPAN_S))
    series = utility_series(db, "m")
    assert len(series["t"]) <= MAX_BINS
    assert series["bin_s"] % BIN_S == 0 and series["bin_s"] >= SPAN_S / MAX_BINS
    assert series["t_start"] == T_IMAGES - SPAN_S
    assert {d: v["total"] for d, v in series["drones"].items()} == {"uav1": 3.0, "uav2": 4.0}
    assert all(len(v["utility"]) == len(series["t"]) for v in series["drones"].values())
    # everything fell into the last bin, as it would have into the last 5 s bins
    assert series["drones"]["uav1"]["utility"][-1] == 3.0


def test_a_short_mission_keeps_its_five_second_bins(tmp_path: Path) -> None:
    db = sqlite3.connect(_fill(tmp_path, t_start=T_IMAGES - 0.5 * BIN_S * MAX_BINS))
    series = utility_series(db, "m")
    assert series["bin_s"] == BIN_S and len(series["t"]) == MAX_BINS // 2 + 2


async def test_the_api_reply_stays_small(tmp_path: Path,
                                         aiohttp_client: Callable[..., Any]) -> None:
    _fill(tmp_path / "gs", t_start=T_IMAGES - SPAN_S)
    config = GroundConfig(fleet_key=b"report-span-fleet-key-00000000", fleet_id=3,
                          command_key=TEST_COMMAND_KEY, data_dir=tmp_path / "gs", mission="m",
                          udp_host="127.0.0.1", udp_port=0, fsync=False)
    client = await aiohttp_client(create_app(config, token=TOKEN))
    resp = await client.get("/api/report", headers={"Authorization": f"Bearer {TOKEN}"})
    body = await resp.read()
    assert resp.status == 200 and len(body) < 100_000, len(body)
    assert json.loads(body)["drones"]["uav2"]["total"] == 4.0
