"""The shipped ``uav-ground-station run`` (a real subprocess, INFO logging) fed what an
attacker on the radio link can send: random bytes, every truncation of a real fragment,
bit flips, a 65 kB datagram, another key's image, a fleet-key holder's random bodies of
every packet kind, and replays of a real image. Expected: each counted and dropped, no
traceback, nothing stored but the one real image, the station still serving."""

from __future__ import annotations

import asyncio
import random
import socket
import subprocess
import sys
from pathlib import Path

import aiohttp

from companion.protocol.wire import PacketKind
from ground_station.fake_drone import FakeDrone, synthetic_jpeg
from ground_station.storage import Storage
from tests.integration.test_ground_station_cli import free_port, wait_http
from tests.keys import TEST_FLEET_KEY, write_test_keys
from tests.processes import interrupt

STATION = Path(sys.executable).parent / "uav-ground-station"
REPLAYS = 5


async def _stats(http_port: int, token: str) -> dict:  # type: ignore[type-arg]
    async with (aiohttp.ClientSession() as session,
                session.get(f"http://127.0.0.1:{http_port}/api/stats",
                            headers={"Authorization": f"Bearer {token}"}) as resp):
        assert resp.status == 200
        return await resp.json()  # type: ignore[no-any-return]


async def test_hostile_datagrams_are_counted_and_nothing_is_stored(tmp_path: Path) -> None:
    udp_port, http_port = free_port(socket.SOCK_DGRAM), free_port(socket.SOCK_STREAM)
    data = tmp_path / "data"
    write_test_keys(data / "keys")
    log = tmp_path / "station.log"
    with open(log, "w") as stderr:
        station = subprocess.Popen(
            [str(STATION), "run", "--data-dir", str(data), "--mission", "wire",
             "--udp-port", str(udp_port), "--http-port", str(http_port)],
            stdout=subprocess.DEVNULL, stderr=stderr)
    rng = random.Random(7)
    good = FakeDrone("uav1", fleet_id=1, key=TEST_FLEET_KEY, ground=("127.0.0.1", udp_port))
    other = FakeDrone("uav9", fleet_id=1, key=bytes(range(32)), ground=("127.0.0.1", udp_port))
    try:
        await wait_http(f"http://127.0.0.1:{http_port}/api/stats")
        token = (data / "token").read_text().strip()
        await good.open()
        await other.open()
        jpeg = synthetic_jpeg(1, red=0.3, label="uav1")
        fragments = good.datagrams_for_image(jpeg, data={"red": 0.3})
        hostile = [rng.randbytes(rng.randint(0, 1500)) for _ in range(200)]
        hostile += [fragments[0][:cut] for cut in range(0, len(fragments[0]), 9)]
        for _ in range(100):
            flipped = bytearray(rng.choice(fragments))
            flipped[rng.randrange(len(flipped))] ^= 1 << rng.randrange(8)
            hostile.append(bytes(flipped))
        hostile.append(b"\x00" * 65_000)
        hostile += other.datagrams_for_image(jpeg, data={"red": 0.9})
        hostile += [good.encoder._pack(kind, rng.randbytes(rng.randint(0, 1100)), good.clock())
                    for kind in PacketKind for _ in range(50)]
        for datagram in hostile:
            good.sendto(datagram)
            await asyncio.sleep(0)
        await asyncio.sleep(1.0)
        before = await _stats(http_port, token)
        assert before["storage"]["images_stored"] == 0 and before["decoder"]["messages"] == 0
        dropped = sum(before["decoder"][k] for k in ("malformed", "bad_tag", "oversize"))
        assert dropped >= 300, before["decoder"]

        real = good.datagrams_for_image(jpeg, data={"red": 0.3})
        for datagram in real * (1 + REPLAYS):
            good.sendto(datagram)
        async with asyncio.timeout(15):
            while (after := await _stats(http_port, token))["storage"]["images_stored"] < 1:
                await asyncio.sleep(0.2)
        assert after["decoder"]["messages"] == 1
        assert after["decoder"]["replayed"] - before["decoder"]["replayed"] == \
            REPLAYS * len(real)
        assert station.poll() is None
    finally:
        good.close()
        other.close()
        interrupt(station, timeout_s=20)
    assert station.returncode == 0
    assert "Traceback" not in log.read_text()
    storage = Storage(data, readonly=True)
    try:
        assert [(r.sender, r.seq) for r in storage.images("wire", limit=10)] == \
            [("uav1", good.seq)]
    finally:
        storage.close()
