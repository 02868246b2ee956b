"""The ground station on a real full disk: a small tmpfs as its data directory.

Needs root (mount); elsewhere it skips. The unit tests simulate ENOSPC; this one lets the
kernel say it, for image files, SQLite and the mission log alike.
"""

from __future__ import annotations

import asyncio
import os
import shutil
import subprocess
from collections.abc import AsyncIterator, Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from aiohttp.test_utils import TestClient

from ground_station.app import create_app
from ground_station.fake_drone import FakeDrone
from ground_station.keys import LINK, STORAGE
from tests.integration.test_ground_station_udp import AUTH, KEY, TOKEN, make_config
from tests.keys import TEST_COMMAND_PUB
from utility_specs.files import read_log

DISK_BYTES = 3 * 1024 * 1024
IMAGE_BYTES = 150_000


@pytest.fixture
def small_disk(tmp_path: Path) -> Iterator[Path]:
    mount_point = tmp_path / "gs"
    mount_point.mkdir()
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("a real full disk needs a tmpfs mount: run the tests as root to enable")
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={DISK_BYTES}", "tmpfs",
                           str(mount_point)], capture_output=True, text=True, check=False)
    if done.returncode != 0:
        pytest.skip(f"mount -t tmpfs failed ({done.stderr.strip()}): needs CAP_SYS_ADMIN")
    try:
        yield mount_point
    finally:
        subprocess.run(["umount", "-l", str(mount_point)], check=False)


@pytest.fixture
async def station(
    small_disk: Path, aiohttp_client: Callable[..., Any]
) -> AsyncIterator[TestClient[Any, Any]]:
    client: TestClient[Any, Any] = await aiohttp_client(
        create_app(make_config(small_disk), token=TOKEN)
    )
    yield client


async def until(predicate: Callable[[], bool], timeout: float = 10.0) -> None:
    async with asyncio.timeout(timeout):
        while not predicate():
            await asyncio.sleep(0.01)


@pytest.mark.timeout(120)
async def test_a_full_disk_is_reported_telemetry_keeps_flowing_and_storage_recovers(
    station: TestClient[Any, Any], small_disk: Path, caplog: pytest.LogCaptureFixture
) -> None:
    app = station.server.app
    link, storage = app[LINK], app[STORAGE]
    drone = FakeDrone("d1", fleet_id=3, key=KEY, ground=link.local_addr,
                      command_public_key=TEST_COMMAND_PUB)
    await drone.open()
    images = 2 * DISK_BYTES // IMAGE_BYTES  # twice what fits
    for _ in range(images):
        drone.send_image(os.urandom(IMAGE_BYTES), data={"red": 0.1})
        await asyncio.sleep(0.02)  # a paced sender: no drops in the socket buffer
    await until(lambda: link.counters["images"] == images)
    await storage.flush()
    assert storage.errors > 10
    # every error is counted, but the log is not flooded: one line per 10 s
    logged = [r for r in caplog.records if r.name == "ground_station.store_service"]
    assert 1 <= len(logged) <= 2, [r.getMessage() for r in logged]
    alerts = (await (await station.get("/api/fleet", headers=AUTH)).json())["alerts"]
    assert any("disk full" in a["text"] for a in alerts if a["kind"] == "storage"), alerts

    # telemetry keeps flowing to the dashboard while nothing can be written
    drone.send_telemetry("battery", {"level": 0.42})
    await until(lambda: link.counters["messages"] == images + 1)
    fleet = await (await station.get("/api/fleet", headers=AUTH)).json()
    assert fleet["drones"][0]["battery"] == pytest.approx(0.42)

    # an operator frees space: the next image is stored again, file and row
    stored_before = storage.images_stored
    for path in sorted((small_disk / "missions").rglob("*.jpg"))[: images // 4]:
        path.unlink()
    seq = drone.send_image(os.urandom(IMAGE_BYTES), data={"red": 0.9})
    await until(lambda: link.counters["images"] == images + 1)
    await storage.flush()
    assert storage.images_stored == stored_before + 1
    rows = await storage.read(lambda s: s.images("it", order="time", limit=1000))
    row = next(r for r in rows if r.seq == seq)
    assert row.path is not None and (storage.root / row.path).stat().st_size == IMAGE_BYTES
    stats = await (await station.get("/api/stats", headers=AUTH)).json()
    assert stats["storage"]["errors"] == storage.errors
    # the mission log still parses: what a full disk cut off did not leave a broken line
    log = read_log(storage.root / "missions" / "it" / "mission_log.jsonl")
    assert seq in {m.seq for m in log.messages if m.sender == "d1"}
    drone.close()
