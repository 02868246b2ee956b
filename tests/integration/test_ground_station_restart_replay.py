"""Replays across a ground-station restart (issue 13 item 4): a drone streams for 12 s while
everything is captured, the station is killed (-9: no orderly save) and started again, and
at 23 s every capture (11 to 23 s old, fresh by the 30 s clock rule) is replayed. None is
accepted or stored twice, and the drone's new images still are. Real ``uav-ground-station``
processes, real UDP; effects read from the HTTP API and the database."""

from __future__ import annotations

import asyncio
import os
import signal
import socket
import sqlite3
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import aiohttp
import pytest

from ground_station.fake_drone import FakeDrone, synthetic_jpeg
from tests.keys import TEST_COMMAND_PUB, TEST_FLEET_KEY, write_test_keys

SCRIPT = Path(sys.executable).parent / "uav-ground-station"
STATION = [str(SCRIPT)] if SCRIPT.exists() else [sys.executable, "-m", "ground_station.cli"]
FLEET = 14


def free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def start_station(config: Path) -> subprocess.Popen[str]:
    return subprocess.Popen([*STATION, "run", "--config", str(config)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})


async def stats(http: str, token: str) -> dict[str, Any]:
    headers = {"Authorization": f"Bearer {token}"}
    async with asyncio.timeout(20), aiohttp.ClientSession() as session:
        while True:
            try:
                async with session.get(f"{http}/api/stats", headers=headers) as resp:
                    if resp.status == 200:
                        result: dict[str, Any] = await resp.json()
                        return result
            except aiohttp.ClientError:
                pass
            await asyncio.sleep(0.1)


def stored_images(db: Path) -> list[tuple[str, int]]:
    with sqlite3.connect(db) as conn:
        return sorted(conn.execute("SELECT sender, seq FROM images").fetchall())


@pytest.mark.timeout(120)
async def test_captures_are_not_accepted_again_after_a_station_restart(tmp_path: Path) -> None:
    udp_port, http_port = free_port(socket.SOCK_DGRAM), free_port(socket.SOCK_STREAM)
    write_test_keys(tmp_path / "data" / "keys")
    config = tmp_path / "gs.toml"
    config.write_text(
        f'[ground_station]\nfleet_id = {FLEET}\ndata_dir = "data"\nmission = "replay"\n'
        f'udp_host = "127.0.0.1"\nudp_port = {udp_port}\nhttp_port = {http_port}\n'
        "fsync = false\n"
    )
    http = f"http://127.0.0.1:{http_port}"
    station = start_station(config)
    try:
        token = ""
        async with asyncio.timeout(20):
            while not (tmp_path / "data" / "token").exists():
                await asyncio.sleep(0.05)
            while not token:
                token = (tmp_path / "data" / "token").read_text().strip()
        await stats(http, token)
        drone = FakeDrone("uav1", fleet_id=FLEET, key=TEST_FLEET_KEY,
                          ground=("127.0.0.1", udp_port), command_public_key=TEST_COMMAND_PUB)
        captured: list[bytes] = []
        send = drone.sendto

        def capture(datagram: bytes) -> None:  # the attacker's copy of everything on the air
            captured.append(datagram)
            send(datagram)

        drone.sendto = capture  # type: ignore[method-assign]
        await drone.open()
        t0 = time.time()
        jpeg = synthetic_jpeg(1, red=0.2, label="uav1")
        sent_images = 0
        while time.time() - t0 < 12.0:
            drone.send_image(jpeg, data={"red": 0.2})
            sent_images += 1
            drone.send_telemetry("battery", {"level": 0.8})
            await asyncio.sleep(0.25)
        await asyncio.sleep(1.5)  # the last images stored, the replay state saved since
        before = await stats(http, token)
        assert before["storage"]["images_stored"] == sent_images
    finally:
        station.send_signal(signal.SIGKILL)
        station.wait(10)
    db = tmp_path / "data" / "ground_station.sqlite3"
    stored_before = stored_images(db)
    assert len(stored_before) == sent_images

    station = start_station(config)
    try:
        await stats(http, token)
        await asyncio.sleep(max(0.0, t0 + 23.0 - time.time()))
        drone.sendto = send  # type: ignore[method-assign]
        for datagram in captured:  # 11 to 23 s old now
            send(datagram)
        await asyncio.sleep(1.0)
        after = await stats(http, token)
        assert after["decoder"]["replayed"] == len(captured)
        assert after["decoder"]["accepted"] == 0 and after["storage"]["images_stored"] == 0
        # the drone itself is still heard: its next images are stored
        new_seqs = [drone.send_image(jpeg, data={"red": 0.2}) for _ in range(3)]
        async with asyncio.timeout(10):
            while (await stats(http, token))["storage"]["images_stored"] < 3:
                await asyncio.sleep(0.1)
    finally:
        drone.close()
        station.send_signal(signal.SIGINT)
        _, err = station.communicate(timeout=20)
    assert station.returncode == 0, err[-2000:]
    assert "Traceback" not in err
    assert stored_images(db) == sorted(stored_before + [("uav1", s) for s in new_seqs])
