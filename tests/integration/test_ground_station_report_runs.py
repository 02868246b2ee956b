"""The mission report of a mission started, ended and started again (operator check, audit
13): a real ``uav-ground-station run`` and a drone streaming images over UDP.

Before: ``/api/report`` and ``utility.png`` counted from the latest start only (5 of 81
stored images in one operator run), saying nothing of the rest.
"""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from ground_station.fake_drone import synthetic_jpeg
from tests.integration.test_ground_station_mission_restarts import Station, drone, until


@pytest.mark.timeout(60)
async def test_the_report_covers_every_run_of_the_mission(tmp_path: Path) -> None:
    station = Station(tmp_path)
    await station.start()
    fake = await drone(station)
    jpeg = synthetic_jpeg(1, red=0.2, label="drone1")

    async def images(n: int) -> None:
        for _ in range(n):
            fake.send_image(jpeg, data={"red": 0.2})
            await asyncio.sleep(0.1)

    async def stored(n: int) -> bool:
        return bool((await station.api("GET", "/api/stats"))["storage"]["images_stored"] >= n)

    try:
        await images(2)  # before the first start: not the mission's
        await until(lambda: stored(2))
        for verb, n in (("start", 4), ("end", 0), ("start", 3)):
            await station.api("POST", f"/api/mission/{verb}", {})  # now
            await asyncio.sleep(0.3)
            await images(n)
        await until(lambda: stored(9))
        report = await station.api("GET", "/api/report")
    finally:
        fake.close()
        station.stop()
    utility = report["drones"]["drone1"]
    assert utility["total"] == pytest.approx(7 * 3.0)  # q * (1 + 10 * 0.2) each; was 3 * 3.0
    assert sum(utility["utility"]) == pytest.approx(utility["total"])
    assert report["images"] == 7 and report["images_outside"] == 2  # what it covers
    [first, second] = report["runs"]
    assert first[1] is not None and second[1] is None and first[1] < second[0]
    assert report["t_start"] == first[0]
