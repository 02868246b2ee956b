"""HTTP cannot starve the station (issue 13 item 6): a real ``uav-ground-station`` with a
256-descriptor limit gets 300 idle TCP connections and keeps storing images; the idle
connections are closed after ``http_idle_timeout_s``; tokens and login codes never reach
the access log (request line or Referer)."""

from __future__ import annotations

import asyncio
import os
import resource
import socket
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import aiohttp
import pytest

from ground_station.fake_drone import FakeDrone, synthetic_jpeg
from tests.keys import TEST_COMMAND_PUB, TEST_FLEET_KEY, write_test_keys
from tests.processes import interrupt

SCRIPT = Path(sys.executable).parent / "uav-ground-station"
STATION = [str(SCRIPT)] if SCRIPT.exists() else [sys.executable, "-m", "ground_station.cli"]
FLEET = 15
FD_LIMIT = 256
IDLE_CONNECTIONS = 300


def free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _low_fd_limit() -> None:  # in the child, before exec: a small host
    resource.setrlimit(resource.RLIMIT_NOFILE, (FD_LIMIT, FD_LIMIT))


def images_in(db: Path) -> int:
    if not db.exists():
        return 0
    with sqlite3.connect(db, timeout=5) as conn:
        return int(conn.execute("SELECT COUNT(*) FROM images").fetchone()[0])


@pytest.mark.timeout(90)
async def test_idle_connections_do_not_stop_storage_and_secrets_stay_out_of_logs(
    tmp_path: Path,
) -> None:
    udp_port, http_port = free_port(socket.SOCK_DGRAM), free_port(socket.SOCK_STREAM)
    write_test_keys(tmp_path / "data" / "keys")
    config = tmp_path / "gs.toml"
    config.write_text(
        f'[ground_station]\nfleet_id = {FLEET}\ndata_dir = "data"\nmission = "limits"\n'
        f'udp_host = "127.0.0.1"\nudp_port = {udp_port}\nhttp_port = {http_port}\n'
        "fsync = false\nhttp_max_connections = 64\nhttp_idle_timeout_s = 3.0\n"
    )
    http = f"http://127.0.0.1:{http_port}"
    err_path = tmp_path / "station.err"
    with open(err_path, "w") as err_file:
        station = subprocess.Popen([*STATION, "run", "--config", str(config)],
                                   stdout=subprocess.DEVNULL, stderr=err_file, text=True,
                                   preexec_fn=_low_fd_limit,
                                   env={**os.environ, "PYTHONUNBUFFERED": "1"})
    idle: list[socket.socket] = []
    try:
        token_file = tmp_path / "data" / "token"
        async with asyncio.timeout(30):
            while not (token_file.exists() and token_file.read_text().strip()):
                await asyncio.sleep(0.05)
        token = token_file.read_text().strip()
        headers = {"Authorization": f"Bearer {token}"}
        async with aiohttp.ClientSession() as session:
            async with asyncio.timeout(30):
                while True:
                    try:
                        async with session.get(f"{http}/api/stats", headers=headers) as r:
                            if r.status == 200:
                                break
                    except aiohttp.ClientError:
                        pass
                    await asyncio.sleep(0.1)
            async with session.get(
                f"{http}/?login=SECRETLOGIN123&x=1", allow_redirects=False,
                headers={"Referer": "http://elsewhere/?token=REFSECRET456"},
            ) as r:
                assert r.status == 303

        for _ in range(IDLE_CONNECTIONS):  # connect and say nothing (a scanner, slowloris)
            s = socket.create_connection(("127.0.0.1", http_port), timeout=5)
            idle.append(s)
        opened = time.monotonic()

        drone = FakeDrone("uav1", fleet_id=FLEET, key=TEST_FLEET_KEY,
                          ground=("127.0.0.1", udp_port), command_public_key=TEST_COMMAND_PUB)
        await drone.open()
        for i in range(4):
            drone.send_image(synthetic_jpeg(i, red=0.1, label="uav1"), data={"red": 0.1})
            await asyncio.sleep(0.05)
        db = tmp_path / "data" / "ground_station.sqlite3"
        async with asyncio.timeout(15):
            while images_in(db) < 4:
                await asyncio.sleep(0.1)
        drone.close()

        # every idle connection is closed by the station: at once beyond the cap, after the
        # idle timeout below it
        closed = 0
        for s in idle:
            s.settimeout(max(0.1, opened + 8.0 - time.monotonic()))
            try:
                closed += s.recv(1) == b""
            except ConnectionResetError:
                closed += 1
            except TimeoutError:
                pass
        assert closed == IDLE_CONNECTIONS
        async with aiohttp.ClientSession() as session, session.get(
            f"{http}/api/stats", headers=headers
        ) as r:
            assert r.status == 200
            stats = await r.json()
        assert stats["storage"]["images_stored"] == 4 and stats["storage"]["errors"] == 0
    finally:
        for s in idle:
            s.close()
        interrupt(station, timeout_s=20)
    err = err_path.read_text()
    assert station.returncode == 0, err[-3000:]
    assert "Traceback" not in err
    assert "SECRETLOGIN123" not in err and "REFSECRET456" not in err and token not in err
    assert "login=***" in err and "token=***" in err
    assert len(err) < 64 * 1024, f"{len(err)} bytes of log"
