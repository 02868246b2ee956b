"""Issue 18: a drone's fallback share (status field) reaches the ground station's API, and
the fleet summary prints it per drone."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from test_ground_station_udp import AUTH, TOKEN, drone_for, make_config, until

from ground_station.app import create_app
from ground_station.keys import LINK
from sitl.fleet import format_summary


async def test_fleet_api_shows_each_drones_fallback_share(
        tmp_path: Path, aiohttp_client: Callable[..., Any]) -> None:
    station = await aiohttp_client(create_app(make_config(tmp_path / "gs"), token=TOKEN))
    drone = await drone_for(station)
    drone.send_telemetry("status", {"mode": "GUIDED", "fallback_share": 0.004})
    fleet = station.server.app[LINK].fleet
    await until(lambda: "d1" in fleet.drones and fleet.drones["d1"].fallback_share is not None)
    body = await (await station.get("/api/fleet", headers=AUTH)).json()
    drones = body["drones"] if isinstance(body, dict) and "drones" in body else body
    [d1] = [d for d in (drones.values() if isinstance(drones, dict) else drones)
            if d["drone"] == "d1"]
    assert d1["fallback_share"] == 0.004
    drone.send_telemetry("status", {"mode": "GUIDED", "fallback_share": 7.0})  # not a share
    drone.send_telemetry("status", {"mode": "AUTO"})
    await until(lambda: fleet.drones["d1"].mode == "AUTO")
    assert fleet.drones["d1"].fallback_share == 0.004
    drone.close()


def test_fleet_summary_prints_the_fallback_share() -> None:
    row = {"generated": 10, "sent": 5, "received": 5, "stored": 5, "fps": 1.0,
           "latency_mean_s": 0.1, "mean_red": 0.1, "fallback_share": 0.0042, "decisions": 240}
    summary = {"policy": "mcts", "duration_s": 10.0, "drones": {"d1": row, "d2": {
        **row, "fallback_share": None}}, "utility": None, "link": None,
        "run_dir": "/x", "data": {"images": "/x/i", "ground_station_db": "/x/db",
                                  "ground_station_log": "/x/l", "companion_logs": [],
                                  "process_logs": "/x/p"}}
    lines = format_summary(summary).splitlines()
    assert lines[1].split()[-1] == "fallback"
    assert lines[2].split()[-2:] == ["0.4", "%"]
    assert lines[3].split()[-1] == "-"
