"""The shipped ``uav-companion run`` with a camera that is not plugged in: it runs on and
streams its telemetry, says once in its log (and on its status, for the dashboard) that the
camera cannot be opened, and stops cleanly. Before, it exited 2 at start ("cannot start:
camera.source: cannot open camera"), so the drone sent nothing at all, and OpenCV printed
three lines of its own to stderr at every attempt."""

from __future__ import annotations

import asyncio
import json
import socket
import time
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from companion.protocol import Decoder, MessageReassembled
from tests.companion_process import ground_station_toml, start_companion, stop_companion, until

KEY = b"camera-missing-test-fleet-key"
FLEET = 14


class Station(asyncio.DatagramProtocol):
    def __init__(self) -> None:
        self.decoder = Decoder(FLEET, KEY, local_id="gs")
        self.statuses: list[dict[str, object]] = []
        self.types: set[str] = set()

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        self.decoder.receive_datagram(data, addr, time.time())
        while (event := self.decoder.next_event()) is not None:
            if isinstance(event, MessageReassembled):
                self.types.add(event.message.type)
                if event.message.type == "status":
                    self.statuses.append(dict(event.message.data))

    def texts(self) -> list[str]:
        return [str(s["statustext"]) for s in self.statuses if "statustext" in s]


@pytest.fixture
async def station() -> AsyncIterator[tuple[Station, int]]:
    loop = asyncio.get_running_loop()
    transport, proto = await loop.create_datagram_endpoint(Station, local_addr=("127.0.0.1", 0))
    yield proto, transport.get_extra_info("sockname")[1]
    transport.close()


@pytest.mark.timeout(120)
async def test_a_missing_camera_does_not_stop_the_companion(
        station: tuple[Station, int], tmp_path: Path) -> None:
    gs, gs_port = station
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:  # nobody answers MAVLink here
        s.bind(("127.0.0.1", 0))
        mavlink_port = s.getsockname()[1]
    config = tmp_path / "d1.toml"
    config.write_text(f"""
[drone]
id = "d1"
[mavlink]
url = "udpout:127.0.0.1:{mavlink_port}"
[camera]
source = "/dev/video-not-plugged-in"
[mission]
spec = "builtin:image_streaming"
{ground_station_toml(gs_port, fleet_id=FLEET, fleet_key=KEY)}
[budgets]
mcts_iterations = 20
""")
    proc = start_companion(config)
    try:
        await until(lambda: any("camera" in t for t in gs.texts()), 60, proc, poll_s=0.1)
        await asyncio.sleep(3.0)  # more failed attempts to open it: still said once
        assert proc.poll() is None
    finally:
        code, err = stop_companion(proc)
    assert code == 0, err[-2000:]
    assert gs.texts().count("camera: cannot open camera '/dev/video-not-plugged-in' "
                            "(trying again every 2 s)") == 1, gs.texts()
    assert "status" in gs.types
    records = [json.loads(line) for line in err.splitlines() if line.startswith("{")]
    camera = [r for r in records if r["logger"] == "companion.camera"]
    assert [r["level"] for r in camera] == ["warning"], camera
    assert "[ WARN" not in err and "Traceback" not in err, err[-2000:]
