"""Issue 13, item 1, over real UDP: what a receiver report promises, and a storage writer
that cannot die quietly.

An image reported delivered is durable (row committed, file under its final name); one that
could not be stored is never reported, is counted in ``/api/stats`` and alerted, and the
station keeps storing what comes next. The tmpfs variant needs root (mount); elsewhere the
simulated variant covers the same path.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import json
import logging
import os
import shutil
import sqlite3
import subprocess
from collections.abc import AsyncIterator, Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from aiohttp.test_utils import TestClient

from companion.protocol.wire import DATA_FIXED, METADATA_LEN, STATUS_FIXED, PacketKind
from ground_station.app import create_app
from ground_station.fake_drone import FakeDrone
from ground_station.keys import LINK, STORAGE
from ground_station.storage import Storage
from tests.integration.test_ground_station_udp import AUTH, KEY, TOKEN, make_config


async def until(predicate: Callable[[], bool], timeout: float = 10.0) -> None:
    async with asyncio.timeout(timeout):
        while not predicate():
            await asyncio.sleep(0.01)


@contextlib.asynccontextmanager
async def running_station(
    data_dir: Path, aiohttp_client: Callable[..., Any]
) -> AsyncIterator[TestClient[Any, Any]]:
    client: TestClient[Any, Any] = await aiohttp_client(
        create_app(make_config(data_dir), token=TOKEN)
    )
    try:
        yield client
    finally:
        await client.close()


@pytest.fixture
async def station(
    tmp_path: Path, aiohttp_client: Callable[..., Any]
) -> AsyncIterator[TestClient[Any, Any]]:
    async with running_station(tmp_path / "gs", aiohttp_client) as client:
        yield client


async def drone_for(client: TestClient[Any, Any], name: str = "d1") -> FakeDrone:
    drone = FakeDrone(name, fleet_id=3, key=KEY, ground=client.server.app[LINK].local_addr)
    await drone.open()
    return drone


def reported(drone: FakeDrone) -> set[int]:
    return {e.seq for r in drone.reports for e in r.report.entries if e.sender == drone.drone_id}


async def stored_seqs(client: TestClient[Any, Any]) -> set[int]:
    storage = client.server.app[STORAGE]
    await storage.flush()
    rows = await storage.read(lambda s: s.images("it", order="time", limit=1000))
    return {r.seq for r in rows if r.path is not None and (storage.root / r.path).is_file()}


async def stats(client: TestClient[Any, Any]) -> dict[str, Any]:
    result: dict[str, Any] = await (await client.get("/api/stats", headers=AUTH)).json()
    return result


async def storage_alerts(client: TestClient[Any, Any]) -> list[str]:
    fleet = await (await client.get("/api/fleet", headers=AUTH)).json()
    return [a["text"] for a in fleet["alerts"] if a["kind"] == "storage"]


async def send_paced(drone: FakeDrone, n: int, size: int = 3000) -> list[int]:
    seqs = []
    for i in range(n):
        seqs.append(drone.send_image(bytes([i % 251]) * size, data={"red": 0.2}))
        await asyncio.sleep(0.002)
    return seqs


async def test_only_stored_images_are_reported_delivered(
    station: TestClient[Any, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Every other image hits a full disk: exactly the stored ones are reported."""
    real = Storage._write_file

    def full_for_odd_payloads(self: Storage, relpath: Path, payload: bytes) -> None:
        if payload[0] % 2:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real(self, relpath, payload)

    monkeypatch.setattr(Storage, "_write_file", full_for_odd_payloads)
    link = station.server.app[LINK]
    drone = await drone_for(station)
    seqs = await send_paced(drone, 10)
    await until(lambda: link.counters["images"] == 10)
    stored = await stored_seqs(station)
    assert stored == set(seqs[0::2])  # payload bytes 0, 2, 4...: even ones land
    await until(lambda: reported(drone) >= stored)
    await asyncio.sleep(0.3)  # several more report periods: the failed ones never appear
    assert reported(drone) == stored
    s = await stats(station)
    assert s["storage"]["not_stored"] == 5 and s["link"]["not_stored"] == 5
    assert s["storage"]["errors"] >= 5
    assert any("disk full" in text for text in await storage_alerts(station))
    drone.close()


async def test_a_disk_full_at_mission_start_is_survived_simulated(
    station: TestClient[Any, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Issue 13 (a) without root: SQLite says "database or disk is full" (index and mission
    bounds) and files get ENOSPC while the first image after a mission start arrives.
    The writer used to die there: 0 of the next 60 images were stored."""
    full = True
    real_write, real_mark, real_index = Storage._write_file, Storage.mark_mission, Storage._index

    def write_file(self: Storage, relpath: Path, payload: bytes) -> None:
        if full:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real_write(self, relpath, payload)

    def mark_mission(self: Storage, *args: Any, **kwargs: Any) -> None:
        if full:
            raise sqlite3.OperationalError("database or disk is full")
        real_mark(self, *args, **kwargs)

    def index(self: Storage, *args: Any, **kwargs: Any) -> Any:
        if full:
            self.db.execute("BEGIN")  # fail inside a transaction, as SQLite does
            raise sqlite3.OperationalError("database or disk is full")
        return real_index(self, *args, **kwargs)

    monkeypatch.setattr(Storage, "_write_file", write_file)
    monkeypatch.setattr(Storage, "mark_mission", mark_mission)
    monkeypatch.setattr(Storage, "_index", index)
    link = station.server.app[LINK]
    drone = await drone_for(station)
    drone.send_telemetry("battery", {"level": 0.9})
    await until(lambda: link.counters["messages"] == 1)
    response = await station.post("/api/mission/start", headers=AUTH, json={"delay_s": 0})
    assert response.status == 200, await response.text()  # the command goes out anyway
    first = drone.send_image(b"\xff\xd8first", data={"red": 0.9})
    await until(lambda: link.counters["images"] == 1)
    await station.server.app[STORAGE].flush()
    assert any("full" in text for text in await storage_alerts(station))
    full = False  # an operator frees space
    seqs = await send_paced(drone, 60)
    await until(lambda: link.counters["images"] == 61)
    assert await stored_seqs(station) == set(seqs)
    await until(lambda: reported(drone) >= set(seqs))
    assert first not in reported(drone)
    s = await stats(station)
    assert s["storage"]["not_stored"] == 2  # the telemetry and the first image
    assert s["storage"]["writer_restarts"] == 0  # survived without even a restart
    drone.close()


@pytest.fixture
def small_disk(tmp_path: Path) -> Iterator[Path]:
    mount_point = tmp_path / "gs"
    mount_point.mkdir()
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("a real full disk needs a tmpfs mount: run the tests as root to enable")
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(mount_point)],
                          capture_output=True, text=True, check=False)
    if done.returncode != 0:
        pytest.skip(f"mount -t tmpfs failed ({done.stderr.strip()}): needs CAP_SYS_ADMIN")
    try:
        yield mount_point
    finally:
        subprocess.run(["umount", "-l", str(mount_point)], check=False)


def fill(directory: Path) -> Path:
    """Write a file until the disk is full; returns it (delete it to free the space)."""
    filler = directory / "filler"
    fd = os.open(filler, os.O_WRONLY | os.O_CREAT, 0o600)
    try:
        with contextlib.suppress(OSError):
            while True:
                os.write(fd, b"\0" * 4096)
    finally:
        os.close(fd)
    return filler


@pytest.mark.timeout(120)
async def test_a_disk_full_at_mission_start_is_survived_tmpfs(
    small_disk: Path, aiohttp_client: Callable[..., Any]
) -> None:
    """Issue 13 (a) on a real tmpfs: it fills just as the first image after a mission start
    arrives; once space is freed the next 60 images are stored and reported."""
    async with running_station(small_disk, aiohttp_client) as station:
        link = station.server.app[LINK]
        drone = await drone_for(station)
        drone.send_telemetry("battery", {"level": 0.9})
        await until(lambda: link.counters["messages"] == 1)
        response = await station.post("/api/mission/start", headers=AUTH, json={"delay_s": 0})
        assert response.status == 200
        await station.server.app[STORAGE].flush()
        filler = fill(small_disk)
        first = drone.send_image(os.urandom(40_000), data={"red": 0.9})
        await until(lambda: link.counters["images"] == 1)
        await station.server.app[STORAGE].flush()
        assert any("full" in text for text in await storage_alerts(station))
        filler.unlink()
        seqs = await send_paced(drone, 60)
        await until(lambda: link.counters["images"] == 61)
        assert await stored_seqs(station) == set(seqs)
        await until(lambda: reported(drone) >= set(seqs))
        assert first not in reported(drone)
        assert (await stats(station))["storage"]["writer_restarts"] == 0
        drone.close()


def hostile_image(drone: FakeDrone, metadata: bytes, payload: bytes) -> bytes:
    """One validly signed DATA datagram with metadata the encoder would never write."""
    drone.seq += 1
    type_raw = b"image"
    body = (DATA_FIXED.pack(drone.seq, drone.clock(), 0, 1, len(payload), len(type_raw))
            + type_raw + METADATA_LEN.pack(len(metadata)) + metadata + payload)
    return drone.encoder._pack(PacketKind.DATA, body, drone.clock())


async def test_a_signed_size_of_2_63_costs_nothing_else(
    tmp_path: Path, aiohttp_client: Callable[..., Any], caplog: pytest.LogCaptureFixture
) -> None:
    """Issue 13 (b): one validly signed message whose size is 2**63 stopped the writer (0 of
    the next 16 images stored, every queued one lost at restart). Now it is a counted
    malformed datagram; the next 16 images are stored, reported and there after a restart.
    A STATUS holding 1e999 is dropped the same way, without a traceback."""
    async with running_station(tmp_path / "gs", aiohttp_client) as station:
        link = station.server.app[LINK]
        drone = await drone_for(station)
        drone.sendto(hostile_image(drone, b'{"z": 9223372036854775808}', b"\xff\xd8poison"))
        drone.sendto(hostile_image(drone, b'{"z": 30, "d": {"red": 1e999}}', b"\xff\xd8inf"))
        status = STATUS_FIXED.pack(0, 4) + b"idle" + b'{"level": 1e999}'
        drone.sendto(drone.encoder._pack(PacketKind.STATUS, status, drone.clock()))
        await until(lambda: link.decoder.counters["malformed"] == 3)
        seqs = await send_paced(drone, 16)
        await until(lambda: link.counters["images"] == 16)
        assert await stored_seqs(station) == set(seqs)
        await until(lambda: reported(drone) >= set(seqs))
        s = await stats(station)
        assert s["decoder"]["malformed"] == 3 and s["storage"]["not_stored"] == 0
        drone.close()
    assert not [r for r in caplog.records if r.exc_info or r.levelno >= logging.ERROR]
    # a restart finds every image that was reported
    async with running_station(tmp_path / "gs", aiohttp_client) as again:
        assert await stored_seqs(again) == set(seqs)
    rows = [json.loads(line) for line in
            (tmp_path / "gs" / "missions" / "it" / "mission_log.jsonl").read_text().splitlines()]
    assert {r["seq"] for r in rows if "seq" in r} == set(seqs)


async def test_back_pressure_refuses_visibly_and_never_reports(
    station: TestClient[Any, Any],
) -> None:
    """A backlog at its bound (here: no room at all) refuses new messages: counted, alerted,
    never reported; with room again the next images are stored and reported."""
    storage = station.server.app[STORAGE]
    link = station.server.app[LINK]
    bound = storage.max_backlog_bytes
    storage.max_backlog_bytes = 0
    drone = await drone_for(station)
    refused = await send_paced(drone, 5)
    await until(lambda: link.counters["images"] == 5)
    s = await stats(station)
    assert s["storage"]["refused"] == 5 and s["storage"]["submitted"] == 0
    assert any("backlog full" in text for text in await storage_alerts(station))
    storage.max_backlog_bytes = bound
    accepted = await send_paced(drone, 5)
    await until(lambda: reported(drone) >= set(accepted))
    await asyncio.sleep(0.2)
    assert reported(drone) == set(accepted) == await stored_seqs(station)
    assert not set(refused) & reported(drone)
    drone.close()
