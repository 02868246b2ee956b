"""The station learns each drone's boot epoch and signs commands for it (issue 13 items 4, 5):
a drone that restarts (new epoch) gets its unacknowledged command again, for the new epoch,
at once; a drone it never heard an epoch from is told 0 and answers with its epoch."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import pytest
from aiohttp.test_utils import TestClient

from ground_station.app import create_app
from ground_station.fake_drone import FakeDrone
from ground_station.keys import LINK
from tests.integration.test_ground_station_udp import AUTH, KEY, TOKEN, make_config, until
from tests.keys import TEST_COMMAND_PUB


@pytest.fixture
async def station(
    tmp_path: Path, aiohttp_client: Callable[..., Any]
) -> AsyncIterator[TestClient[Any, Any]]:
    client: TestClient[Any, Any] = await aiohttp_client(
        create_app(make_config(tmp_path / "gs"), token=TOKEN)
    )
    yield client


def drone(client: TestClient[Any, Any], epoch: int | None = None) -> FakeDrone:
    return FakeDrone("d1", fleet_id=3, key=KEY, ground=client.server.app[LINK].local_addr,
                     command_public_key=TEST_COMMAND_PUB, epoch=epoch, auto_ack=False)


async def test_a_restarted_drone_gets_its_command_for_the_new_epoch(
    station: TestClient[Any, Any],
) -> None:
    link = station.server.app[LINK]
    before = drone(station, epoch=111)
    await before.open()
    await until(lambda: link.command_epochs.get("d1") == 111)
    resp = await station.post("/api/mission/start", json={"delay_s": 30}, headers=AUTH)
    cid = (await resp.json())["command"]["command_id"]
    first = await before.wait_command()
    assert first.command.command_id == cid
    before.close()  # restarts before acknowledging
    # a restart takes longer than a second: packet numbers start at int(now) << 32
    await asyncio.sleep(1.1)

    after = drone(station, epoch=222)
    await after.open()  # announces 222: the station resends without waiting for a retry
    got = await after.wait_command(timeout=2.0)
    assert got.command.command_id == cid
    assert link.command_epochs["d1"] == 222
    assert after.decoder.counters["wrong_epoch"] == 0
    after.close()


async def test_an_unknown_epoch_is_learned_from_the_refusal(
    station: TestClient[Any, Any],
) -> None:
    link = station.server.app[LINK]
    quiet = drone(station, epoch=333)
    quiet.command_public_key = None  # opens without announcing (e.g. its STATUS was lost)
    await quiet.open()
    quiet.send_telemetry("battery", {"level": 0.5})
    await until(lambda: "d1" in link.fleet.drones)
    assert "d1" not in link.command_epochs
    await station.post("/api/mission/start", json={"delay_s": 30}, headers=AUTH)
    got = await quiet.wait_command(timeout=5.0)  # after one refused try (epoch 0)
    assert quiet.decoder.counters["wrong_epoch"] >= 1
    assert link.command_epochs["d1"] == 333 and got.command.name == "start"
    await asyncio.sleep(0)
    quiet.close()
