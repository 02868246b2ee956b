"""The real ``uav-ground-station run`` stops for seconds (SIGSTOP: swap, a full disk's
writes, a paused VM) while its drones go on sending: the datagrams wait in its socket, and
when it runs again no drone is reported lost and no image half received is expired.
Before, its first timer after the stop ran before the socket was read (the loop's wait had
timed out meanwhile): it raised "link lost: nothing heard for 5.2 s" and then "link back"
for all four drones (false alerts, stored and shown on the dashboard), and expired every
image whose other fragments were waiting."""

from __future__ import annotations

import asyncio
import json
import re
import signal
import time
import urllib.request
from pathlib import Path

import pytest

from ground_station.fake_drone import FakeDrone, synthetic_jpeg
from tests.keys import TEST_FLEET_KEY
from tests.station_process import Station, running_station


def _get(station: Station, path: str) -> dict:  # type: ignore[type-arg]
    request = urllib.request.Request(f"http://127.0.0.1:{station.port}{path}",
                                     headers={"Authorization": f"Bearer {station.token}"})
    with urllib.request.urlopen(request, timeout=10) as reply:
        return json.loads(reply.read())  # type: ignore[no-any-return]


async def _fly(drones: list[FakeDrone], stop: asyncio.Event) -> None:
    while not stop.is_set():
        for i, drone in enumerate(drones):
            drone.send_telemetry("position", {"lat_deg": 47.0 + i / 1e3, "lon_deg": 8.0,
                                              "alt_rel_m": 30.0})
        await asyncio.sleep(0.2)


@pytest.mark.timeout(90)
async def test_a_stalled_station_reports_no_drone_lost(tmp_path: Path) -> None:
    with running_station(tmp_path) as station:
        found = re.findall(r"receiving fleet (\d+) on udp://127.0.0.1:(\d+)", station.log_text())
        fleet_id, port = int(found[0][0]), int(found[0][1])
        drones = [FakeDrone(f"d{i}", fleet_id=fleet_id, key=TEST_FLEET_KEY,
                            ground=("127.0.0.1", port)) for i in range(4)]
        for drone in drones:
            await drone.open()
        stop = asyncio.Event()
        flying = asyncio.create_task(_fly(drones, stop))
        try:
            deadline = time.monotonic() + 20
            while len(_get(station, "/api/fleet")["drones"]) < 4:
                assert time.monotonic() < deadline, "the station never heard the drones"
                await asyncio.sleep(0.2)
            await asyncio.sleep(2.0)  # a few ticks of the station's
            station.proc.send_signal(signal.SIGSTOP)
            await asyncio.sleep(5.0)  # link_lost_s is 3 s
            station.proc.send_signal(signal.SIGCONT)
            await asyncio.sleep(3.0)
            fleet = _get(station, "/api/fleet")
            alerts = _get(station, "/api/alerts")["alerts"]
        finally:
            station.proc.send_signal(signal.SIGCONT)
            stop.set()
            await flying
            for drone in drones:
                drone.close()
    assert not [a for a in alerts if a["kind"] == "link"], [a["text"] for a in alerts]
    assert [d["link_lost"] for d in fleet["drones"]] == [False] * 4, fleet
    assert "the station did not run for" in station.log.read_text()


@pytest.mark.timeout(90)
async def test_an_image_half_received_when_the_station_stalled_is_stored(
        tmp_path: Path) -> None:
    """Half an image's fragments arrive, the station stops for 4 s (its reassembly timeout
    is 2 s) and the other half waits in its socket: stored whole. Before, its first timer
    after the stop ran before the socket was read and expired the image."""
    with running_station(tmp_path) as station:
        found = re.findall(r"receiving fleet (\d+) on udp://127.0.0.1:(\d+)", station.log_text())
        drone = FakeDrone("d1", fleet_id=int(found[0][0]), key=TEST_FLEET_KEY,
                          ground=("127.0.0.1", int(found[0][1])))
        await drone.open()
        try:
            jpeg = synthetic_jpeg(3, red=0.1, width=640, height=480)
            fragments = drone.datagrams_for_image(jpeg, data={"red": 0.1})
            assert len(fragments) >= 4
            half = len(fragments) // 2
            for datagram in fragments[:half]:
                drone.sendto(datagram)
            await asyncio.sleep(0.5)  # the station holds a partial image
            station.proc.send_signal(signal.SIGSTOP)
            for datagram in fragments[half:]:
                drone.sendto(datagram)
            await asyncio.sleep(4.0)
            station.proc.send_signal(signal.SIGCONT)
            await asyncio.sleep(1.0)
            images = _get(station, "/api/images")["images"]
            decoder = _get(station, "/api/stats")["decoder"]
        finally:
            station.proc.send_signal(signal.SIGCONT)
            drone.close()
    assert decoder["expired"] == 0, decoder
    assert [image["sender"] for image in images] == ["d1"], images
