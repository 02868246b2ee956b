"""Issue 13 (b) against the real console script: `uav-ground-station run` as a subprocess
(default INFO logging), a key holder sends a signed size of 2**63, a signed 1e999 in image
metadata and in a STATUS, then 16 good images. Expected: three counted malformed
datagrams, no traceback, the 16 images stored, reported, and still there after shutdown
(the bug: 0 of the next 16 stored, every acknowledged image lost at restart)."""

from __future__ import annotations

import asyncio
import socket
import subprocess
import sys
from pathlib import Path

import aiohttp

from companion.protocol.wire import STATUS_FIXED, PacketKind
from ground_station.fake_drone import FakeDrone
from ground_station.storage import Storage
from tests.integration.test_ground_station_cli import free_port, wait_http
from tests.integration.test_ground_station_storage_guarantee import hostile_image, reported
from tests.keys import write_test_keys
from tests.processes import interrupt

KEY = "hostile-cli-fleet-key-0000000"
TOKEN = "hostile-cli-token-0123456789abcdef"
STATION = Path(sys.executable).parent / "uav-ground-station"


async def test_signed_out_of_range_numbers_cost_nothing_else(tmp_path: Path) -> None:
    udp_port, http_port = free_port(socket.SOCK_DGRAM), free_port(socket.SOCK_STREAM)
    data = tmp_path / "data"
    data.mkdir()
    (data / "token").write_text(TOKEN + "\n")
    (data / "token").chmod(0o600)
    write_test_keys(data / "keys", fleet_key=KEY.encode())  # no built-in key any more
    config = tmp_path / "gs.toml"
    config.write_text(
        "[ground_station]\n"
        f'fleet_key = "{KEY}"\nfleet_id = 5\ndata_dir = "data"\nmission = "h"\n'
        f'udp_host = "127.0.0.1"\nudp_port = {udp_port}\nhttp_port = {http_port}\n'
        "report_interval_s = 0.1\n"
    )
    stderr_path = tmp_path / "stderr.txt"
    with open(stderr_path, "w") as stderr:
        station = subprocess.Popen([str(STATION), "run", "--config", str(config)],
                                   stdout=subprocess.DEVNULL, stderr=stderr)
    auth = {"Authorization": f"Bearer {TOKEN}"}
    try:
        await wait_http(f"http://127.0.0.1:{http_port}/api/stats")
        drone = FakeDrone("uav1", fleet_id=5, key=KEY.encode(), ground=("127.0.0.1", udp_port))
        await drone.open()
        drone.sendto(hostile_image(drone, b'{"z": 9223372036854775808}', b"\xff\xd8poison"))
        drone.sendto(hostile_image(drone, b'{"z": 30, "d": {"red": 1e999}}', b"\xff\xd8inf"))
        status = STATUS_FIXED.pack(0, 4) + b"idle" + b'{"level": 1e999}'
        drone.sendto(drone.encoder._pack(PacketKind.STATUS, status, drone.clock()))
        seqs = set()
        for i in range(16):
            seqs.add(drone.send_image(bytes([i]) * 5000, data={"red": 0.1}))
            await asyncio.sleep(0.005)
        async with asyncio.timeout(15):
            while not reported(drone) >= seqs:
                drone.report_event.clear()
                await drone.report_event.wait()
        async with (
            aiohttp.ClientSession() as session,
            session.get(f"http://127.0.0.1:{http_port}/api/stats", headers=auth) as resp,
        ):
            stats = await resp.json()
        assert stats["decoder"]["malformed"] == 3
        assert stats["storage"]["images_stored"] == 16 and stats["storage"]["not_stored"] == 0
        drone.close()
    finally:
        interrupt(station, timeout_s=20)
    assert station.returncode == 0
    assert "Traceback" not in stderr_path.read_text()
    storage = Storage(data, readonly=True)
    try:
        assert {r.seq for r in storage.images("h", limit=100)} == seqs
    finally:
        storage.close()
