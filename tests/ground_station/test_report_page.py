"""The end-of-mission report: utility over time per drone (numbers, page, PNG)."""

from __future__ import annotations

import sqlite3
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ground_station.app import create_app
from ground_station.config import GroundConfig
from ground_station.report_page import color, figure, total_text, utility_series, write_png
from ground_station.storage import Storage

TOKEN = "report-test-token-0123456789"


def _fill(root: Path, mission: str = "m") -> Path:
    storage = Storage(root, fsync=False)
    db = storage.db
    db.execute("INSERT INTO missions (name, t_created, t_start) VALUES (?, 0, 100.0)", (mission,))
    rows = [("uav1", 101.0, 1.0), ("uav1", 104.0, 2.0), ("uav3", 106.0, 11.0),
            ("uav1", 112.0, 1.0), ("uav3", 112.5, 0.5), ("other", 90.0, 7.0)]
    for seq, (sender, t, u) in enumerate(rows):
        db.execute("INSERT INTO images (mission, sender, seq, type, t_gen, t_rcv, size, "
                   "utility) VALUES (?, ?, ?, 'image', ?, ?, 100, ?)",
                   (mission, sender, seq, t - 0.1, t, u))
    path = storage.db_path
    db.close()
    return path


def test_utility_is_summed_per_drone_and_bin_from_the_mission_start(tmp_path: Path) -> None:
    db = sqlite3.connect(_fill(tmp_path))
    series = utility_series(db, "m", bin_s=5.0)
    assert series["t"] == [0.0, 5.0, 10.0]
    assert series["drones"]["uav1"]["utility"] == [3.0, 0.0, 1.0]
    assert series["drones"]["uav3"]["utility"] == [0.0, 11.0, 0.5]
    assert "other" not in series["drones"]  # before the mission start
    assert series["drones"]["uav3"]["total"] == 11.5
    assert (color("uav1"), color("uav3"), color("uav13")) == ("#4aa3ff", "#3fb950", "#4aa3ff")
    assert utility_series(db, "nothing")["drones"] == {}


def test_a_running_mission_shows_only_the_bins_that_are_over(tmp_path: Path) -> None:
    """A live report at 113 s: the bin 110-115 s still fills (uav1 1.0 and uav3 0.5 so far);
    drawn, every drone would seem to drop at the right edge (seen in `make demo`)."""
    db = sqlite3.connect(_fill(tmp_path))
    running = utility_series(db, "m", bin_s=5.0, now=113.0)
    assert running["t"] == [0.0, 5.0]
    assert running["drones"]["uav1"]["utility"] == [3.0, 0.0]
    assert running["drones"]["uav3"] == {"utility": [0.0, 11.0], "total": 11.0,
                                         "total_text": "11.0", "color": "#3fb950"}
    assert utility_series(db, "m", bin_s=5.0, now=115.0)["t"] == [0.0, 5.0, 10.0]
    assert utility_series(db, "m", bin_s=5.0, now=101.0)["t"] == [0.0]  # the first, filling
    db.execute("UPDATE missions SET t_end = 113.0 WHERE name = 'm'")
    ended = utility_series(db, "m", bin_s=5.0, now=113.0)  # over: its last bin is all there is
    assert ended["drones"]["uav1"]["utility"] == [3.0, 0.0, 1.0]


def test_png_legend_covers_no_curve_and_stays_in_the_picture(tmp_path: Path) -> None:
    """Inside the plot's upper right the legend hid drone3's peak (`make demo`, the red drone
    rising at the end); right of the plot it covers nothing and is not cut off."""
    db = sqlite3.connect(_fill(tmp_path))
    fig = figure(utility_series(db, "m", bin_s=5.0))
    renderer = fig.canvas.get_renderer()
    ax = fig.axes[0]
    plot, legend = ax.get_window_extent(renderer), ax.get_legend().get_window_extent(renderer)
    assert legend.x0 >= plot.x1  # beside the plot, not on it
    assert legend.x1 <= fig.bbox.x1 and legend.y0 >= fig.bbox.y0  # whole, in the PNG
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["uav1 (total 4.0)",
                                                                   "uav3 (total 11.5)"]


def test_png_is_written(tmp_path: Path) -> None:
    out = write_png(_fill(tmp_path / "gs"), "m", tmp_path / "run" / "utility.png")
    assert out is not None and out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert write_png(tmp_path / "missing.sqlite3", "m", tmp_path / "x.png") is None


async def test_report_routes_serve_page_numbers_and_png(
        tmp_path: Path, aiohttp_client: Callable[..., Any]) -> None:
    from tests.keys import TEST_COMMAND_KEY

    _fill(tmp_path / "gs", mission="demo")
    config = GroundConfig(fleet_key=b"report-test-fleet-key-00000000", fleet_id=3,
                          command_key=TEST_COMMAND_KEY, data_dir=tmp_path / "gs",
                          mission="demo", udp_host="127.0.0.1", udp_port=0, fsync=False)
    client = await aiohttp_client(create_app(config, token=TOKEN))
    page = await client.get("/report")
    assert page.status == 200 and "Utility over time per drone" in await page.text()
    assert (await client.get("/api/report")).status == 401  # a data read: token needed
    auth = {"Authorization": f"Bearer {TOKEN}"}
    body = await (await client.get("/api/report", headers=auth)).json()
    assert body["drones"]["uav3"]["utility"] == [0.0, 11.0, 0.5]
    png = await client.get("/api/report.png", headers=auth)
    assert png.status == 200 and png.content_type == "image/png"
    assert (tmp_path / "gs" / "missions" / "demo" / "utility.png").read_bytes() == \
        await png.read()


def test_a_database_without_the_bounds_table_reports_from_its_start(tmp_path: Path) -> None:
    """An older station's database, read read-only (``write_png`` after a run): the mission
    row's start, as before."""
    path = _fill(tmp_path)
    db = sqlite3.connect(path)
    db.execute("DROP TABLE mission_bounds")
    db.commit()
    series = utility_series(db, "m", bin_s=5.0)
    assert series["runs"] == [[100.0, None]] and series["images"] == 5
    assert series["drones"]["uav3"]["utility"] == [0.0, 11.0, 0.5]


def test_a_start_while_the_mission_runs_goes_on_with_its_run(tmp_path: Path) -> None:
    """`make demo` starts its mission, then the operator presses "start mission": the report
    covered only the second start on (61 of 74 images "outside the runs", lead, audit 13)."""
    path = _fill(tmp_path)
    db = sqlite3.connect(path)
    db.executemany("INSERT INTO mission_bounds (mission, t_start, t_end, kind) VALUES "
                   "('m', ?, ?, ?)", [(95.0, None, "open"), (100.0, None, "start"),
                                      (108.0, None, "start"), (None, 113.0, "end"),
                                      (None, 114.0, "end")])
    series = utility_series(db, "m", bin_s=5.0)
    assert series["runs"] == [[100.0, 113.0]]
    assert series["images"] == 5 and series["images_outside"] == 1  # "other" at 90 s
    assert series["drones"]["uav1"]["utility"] == [3.0, 0.0, 1.0]


def test_one_bin_is_drawn_as_the_page_draws_it_with_totals_both_legends_print_alike(
        tmp_path: Path) -> None:
    """Seen 8 s into `make demo`: one bin, four drones of one image each. The picture's axis
    ran from -0.04 to 0.04 s and its legend said "total 0" where the page said "total 1"
    (U 0.5 rounded half to even and half up)."""
    db = sqlite3.connect(_fill(tmp_path))
    db.execute("UPDATE images SET utility = 0.5 WHERE sender = 'uav3'")
    series = utility_series(db, "m", bin_s=5.0, now=102.0)
    assert series["t"] == [0.0]
    ax = figure(series).axes[0]
    assert ax.get_xlim() == (0.0, 5.0) and ax.get_ylim()[0] == 0.0
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels == ["uav1 (total 3.0)"]
    assert [total_text(x) for x in (0.5, 0.25, 99.94, 123.4, 0.0)] == [
        "0.5", "0.2", "99.9", "123", "0.0"]
    assert utility_series(db, "m", bin_s=5.0)["drones"]["uav3"]["total_text"] == "1.0"
