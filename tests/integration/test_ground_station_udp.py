"""The ground station against a test sender over real UDP sockets on 127.0.0.1."""

from __future__ import annotations

import asyncio
import random
import time
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import pytest
from aiohttp.test_utils import TestClient

from ground_station.app import create_app
from ground_station.config import GroundConfig
from ground_station.fake_drone import FakeDrone
from ground_station.keys import LINK, STORAGE
from ground_station.storage import Storage
from tests.keys import TEST_COMMAND_KEY, TEST_COMMAND_PUB
from utility_specs.files import read_log

KEY = b"integration-test-fleet-key-0001"
TOKEN = "integration-token-abcdef"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


def make_config(data_dir: Path) -> GroundConfig:
    return GroundConfig(
        fleet_id=3,
        fleet_key=KEY,
        command_key=TEST_COMMAND_KEY,
        data_dir=data_dir,
        mission="it",
        udp_host="127.0.0.1",
        udp_port=0,
        report_interval_s=0.05,
        command_retry_s=0.1,
        reassembly_timeout_s=0.5,
        fsync=True,
    )


@pytest.fixture
async def station(
    tmp_path: Path, aiohttp_client: Callable[..., Any]
) -> AsyncIterator[TestClient[Any, Any]]:
    client: TestClient[Any, Any] = await aiohttp_client(
        create_app(make_config(tmp_path / "gs"), token=TOKEN)
    )
    yield client


async def drone_for(client: TestClient[Any, Any], name: str = "d1") -> FakeDrone:
    drone = FakeDrone(name, fleet_id=3, key=KEY, ground=client.server.app[LINK].local_addr,
                      command_public_key=TEST_COMMAND_PUB)
    await drone.open()
    return drone


async def until(predicate: Callable[[], bool], timeout: float = 5.0) -> None:
    async with asyncio.timeout(timeout):
        while not predicate():
            await asyncio.sleep(0.01)


async def test_images_reassembled_under_loss_and_reordering(
    station: TestClient[Any, Any],
) -> None:
    """Shuffled fragments of complete images arrive; an image missing one fragment is lost
    whole (expired, counted) and never half-stored."""
    app = station.server.app
    drone = await drone_for(station)
    rng = random.Random(4)
    sent: dict[int, bytes] = {}
    lost_seq = None
    datagrams: list[bytes] = []
    for i in range(6):
        payload = bytes(rng.getrandbits(8) for _ in range(5000 + 997 * i))
        frags = drone.datagrams_for_image(payload, data={"red": i / 10})
        assert len(frags) > 1
        if i == 3:
            lost_seq = drone.seq
            frags = frags[:-1]  # the last fragment never arrives
        else:
            sent[drone.seq] = payload
        datagrams.extend(frags)
    rng.shuffle(datagrams)
    for d in datagrams:
        drone.sendto(d)
    link = app[LINK]
    await until(lambda: link.counters["images"] == len(sent))
    await until(lambda: link.decoder.counters["expired"] == 1, timeout=3.0)
    await app[STORAGE].flush()
    rows = await app[STORAGE].read(lambda s: s.images("it", order="time", limit=100))
    assert {r.seq for r in rows} == set(sent)
    root = app[STORAGE].root
    for row in rows:
        assert row.path is not None
        assert (root / row.path).read_bytes() == sent[row.seq]
    assert lost_seq not in {r.seq for r in rows}
    stats = await (await station.get("/api/stats", headers=AUTH)).json()
    assert stats["drops"]["incomplete"] == 1
    drone.close()


async def test_replay_and_forgery_rejected(station: TestClient[Any, Any]) -> None:
    app = station.server.app
    drone = await drone_for(station)
    [datagram] = drone.datagrams_for_image(b"", data={"level": 0.5}, msg_type="battery")
    drone.sendto(datagram)
    link = app[LINK]
    await until(lambda: link.counters["messages"] == 1)
    drone.sendto(datagram)  # replay
    forged = bytearray(datagram)
    forged[-1] ^= 0x01  # tag no longer matches
    drone.sendto(bytes(forged))
    forger = FakeDrone("d1", fleet_id=3, key=b"some-other-fleet-key-xyz", ground=link.local_addr)
    await forger.open()
    forger.send_telemetry("battery", {"level": 0.1})
    await until(lambda: link.decoder.counters["bad_tag"] == 2)
    await until(lambda: link.decoder.counters["replayed"] == 1)
    stats = await (await station.get("/api/stats", headers=AUTH)).json()
    assert stats["drops"] == {"replayed": 1, "bad_tag": 2}
    assert link.counters["messages"] == 1
    drone.close()
    forger.close()


async def test_reports_reach_the_sender(station: TestClient[Any, Any]) -> None:
    drone = await drone_for(station)
    seq = drone.send_image(b"\xff" * 3000, data={"red": 0.2})
    report = await drone.wait_report(
        lambda r: any(e.sender == "d1" and e.seq == seq for e in r.report.entries)
    )
    entry = next(e for e in report.report.entries if e.seq == seq)
    assert entry.size == 3000
    assert entry.data == {"red": 0.2}
    assert entry.t_rcv >= entry.t_gen
    echo = next(e for e in report.report.echoes if e.sender == "d1")
    assert echo.t_rcv >= echo.t_sent - 1.0
    assert report.reporter == "gs"
    drone.close()


async def test_start_command_reaches_every_drone_and_is_acked(
    station: TestClient[Any, Any],
) -> None:
    app = station.server.app
    d1, d2 = await drone_for(station, "d1"), await drone_for(station, "d2")
    d2.auto_ack = False
    d1.send_telemetry("status", {"mode": "GUIDED"})
    d2.send_telemetry("status", {"mode": "GUIDED"})
    await until(lambda: len(app[LINK].fleet.drones) == 2)
    before = time.time()
    resp = await station.post("/api/mission/start", json={"when": "in 5 s"}, headers=AUTH)
    assert resp.status == 200
    body = await resp.json()
    t_exec = body["command"]["t_exec"]
    assert before + 5.0 <= t_exec <= time.time() + 5.0
    c1 = await d1.wait_command()
    c2 = await d2.wait_command()
    assert c1.command.name == c2.command.name == "start"
    assert c1.command.t_exec == t_exec
    cid = body["command"]["command_id"]
    # d1 acked, d2 did not: d2 keeps getting the command until it acks.
    await until(lambda: len(d2.commands) >= 3)
    mission = await (await station.get("/api/mission", headers=AUTH)).json()
    [cmd] = [c for c in mission["commands"] if c["command_id"] == cid]
    assert cmd["acked_by"] == ["d1"]
    d2.send_status("ack", command_id=cid)
    await until(lambda: "d2" in app[LINK].missions.commands[cid].acked)
    n = len(d2.commands)
    await asyncio.sleep(0.35)
    assert len(d2.commands) == n  # no more resends after the ack
    assert len(d1.commands) == 1
    d1.close()
    d2.close()


async def test_restart_keeps_history(tmp_path: Path, aiohttp_client: Callable[..., Any]) -> None:
    config = make_config(tmp_path / "gs")
    client: TestClient[Any, Any] = await aiohttp_client(create_app(config, token=TOKEN))
    drone = await drone_for(client)
    for i in range(3):
        drone.send_image(bytes([i]) * 4000, data={"red": 0.3 * i, "lat": 51.0, "lon": 17.0})
    drone.send_telemetry("battery", {"level": 0.8})
    link = client.server.app[LINK]
    await until(lambda: link.counters["messages"] == 4)
    drone.close()
    await client.close()  # runs every cleanup context: flushes and closes storage

    again: TestClient[Any, Any] = await aiohttp_client(create_app(config, token=TOKEN))
    images = await (await again.get("/api/images", headers=AUTH)).json()
    assert [im["seq"] for im in images["images"]] == [3, 2, 1]  # by utility: red 0.6 first
    assert images["images"][0]["utility"] == pytest.approx(1 + 10 * 0.6)
    fleet = await (await again.get("/api/fleet", headers=AUTH)).json()
    assert fleet["drones"][0]["latest_image"]["seq"] == 3
    jpeg = await again.get("/api/drones/d1/latest.jpg", headers=AUTH)
    assert await jpeg.read() == bytes([2]) * 4000
    telemetry = await (await again.get("/api/telemetry", headers=AUTH)).json()
    assert telemetry["messages"][0]["data"] == {"level": 0.8}
    log = read_log(Storage(config.data_dir).log_path("it"))
    assert [(m.sender, m.seq, m.receiver) for m in log.messages] == [
        ("d1", 1, "gs"),
        ("d1", 2, "gs"),
        ("d1", 3, "gs"),
        ("d1", 4, "gs"),
    ]
    assert log.t_start == log.messages[0].t_gen
    last_rcv = max(m.t_rcv for m in log.messages if m.t_rcv is not None)
    assert log.t_end is not None and last_rcv <= log.t_end <= time.time()  # closed at shutdown
