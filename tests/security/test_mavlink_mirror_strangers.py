"""A stranger on the ground station's MAVLink mirror (2026-11-25): real sockets on 127.0.0.x.

* On ``mavlink_listen`` (any host that reaches the port may send; MAVLink has no key here) a
  stranger's arm command, mode change, mission upload, parameter write and setpoint reach no
  drone: commands get ``COMMAND_ACK`` DENIED, the rest is counted and dropped, the fleet's
  drones (which obey any command signed by the station) receive nothing, the mission stays.
* With ``mavlink_out`` alone (push to one GCS) the socket is connected to that GCS: before,
  it was unconnected (and on every interface when the GCS was not on this computer), so
  anyone who sent a HEARTBEAT to the pushed traffic's source port got the fleet's stream.
* ``mavlink_listen`` on a wildcard address logs a warning at start, saying why.
"""

from __future__ import annotations

import asyncio
import logging
import socket
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ground_station.app import create_app
from ground_station.cli import _warn_every_interface
from ground_station.config import GroundConfig
from ground_station.fake_drone import FakeDrone
from ground_station.keys import LINK
from tests.integration.test_ground_station_cli import free_port
from tests.keys import TEST_COMMAND_KEY, TEST_COMMAND_PUB

KEY = b"mirror-stranger-fleet-key-00000"
TOKEN = "mirror-stranger-token-0123456789"
MAV_CMD_COMPONENT_ARM_DISARM = 400
MAV_CMD_NAV_TAKEOFF = 22


def _config(tmp_path: Any, **mirror: str) -> GroundConfig:
    return GroundConfig(fleet_id=5, fleet_key=KEY, command_key=TEST_COMMAND_KEY,
                        data_dir=tmp_path / "gs", udp_port=0, link_lost_s=5.0, fsync=False,
                        **mirror)


async def _fly(drone: FakeDrone, stop: asyncio.Event) -> None:
    while not stop.is_set():
        drone.send_telemetry("position", {"lat_deg": 47.0, "lon_deg": 8.0, "alt_rel_m": 10.0})
        drone.send_status("running", info={"mode": "GUIDED", "armed": False,
                                           "autopilot": "ardupilot"})
        await asyncio.sleep(0.2)


def _udp(host: str) -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind((host, 0))
    sock.setblocking(False)
    return sock


async def _receive(sock: socket.socket, seconds: float) -> list[Any]:
    """Every MAVLink message ``sock`` gets within ``seconds``."""
    loop, parser, got = asyncio.get_running_loop(), mavlink.MAVLink(None), []
    deadline = loop.time() + seconds
    while (left := deadline - loop.time()) > 0:
        try:
            data = await asyncio.wait_for(loop.sock_recv(sock, 4096), left)
        except TimeoutError:
            break
        got.extend(parser.parse_buffer(data) or [])
    return got


async def test_a_stranger_on_the_listen_port_commands_no_drone(
        tmp_path: Any, aiohttp_client: Any) -> None:
    mav_port = free_port(socket.SOCK_DGRAM)
    client = await aiohttp_client(create_app(
        _config(tmp_path, mavlink_listen=f"127.0.0.1:{mav_port}"), token=TOKEN))
    drone = FakeDrone("drone3", fleet_id=5, key=KEY, ground=client.server.app[LINK].local_addr,
                      command_public_key=TEST_COMMAND_PUB)
    await drone.open()
    stop = asyncio.Event()
    flying = asyncio.create_task(_fly(drone, stop))
    stranger = _udp("127.0.0.3")
    me = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    auth = {"Authorization": f"Bearer {TOKEN}"}
    try:
        async with client.get("/api/mission", headers=auth) as resp:
            before = await resp.json()
        target = ("127.0.0.1", mav_port)
        attacks = [
            mavlink.MAVLink_command_long_message(3, 1, MAV_CMD_COMPONENT_ARM_DISARM, 0,
                                                 1, 21196, 0, 0, 0, 0, 0),
            mavlink.MAVLink_command_long_message(0, 0, MAV_CMD_COMPONENT_ARM_DISARM, 0,
                                                 1, 0, 0, 0, 0, 0, 0),
            mavlink.MAVLink_command_int_message(3, 1, 6, MAV_CMD_NAV_TAKEOFF, 0, 0,
                                                0, 0, 0, 0, 0, 0, 50),
            mavlink.MAVLink_set_mode_message(3, 1, 9),  # LAND
            mavlink.MAVLink_mission_count_message(3, 1, 1, 0),
            mavlink.MAVLink_mission_item_int_message(3, 1, 0, 6, 21, 1, 1, 0, 0, 0, 0,
                                                     470000000, 80000000, 0, 0),
            mavlink.MAVLink_param_set_message(3, 1, b"ARMING_CHECK", 0, 9),
            mavlink.MAVLink_set_position_target_global_int_message(
                0, 3, 1, 6, 0b110111111000, 470000000, 80000000, 5, 0, 0, 0, 0, 0, 0, 0, 0),
        ]
        for _ in range(3):  # a HEARTBEAT first: the stranger is a client like any GCS
            stranger.sendto(mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3).pack(me),
                            target)
            for attack in attacks:
                stranger.sendto(attack.pack(me), target)
            await asyncio.sleep(0.3)
        got = await _receive(stranger, 1.5)
        acks = [m for m in got if m.get_type() == "COMMAND_ACK"]
        assert {(m.get_srcSystem(), m.command, m.result) for m in acks} == {
            (3, MAV_CMD_COMPONENT_ARM_DISARM, 2), (3, MAV_CMD_NAV_TAKEOFF, 2)}  # DENIED
        assert {m.get_srcSystem() for m in got} == {3}  # it sees the drone: the mirror's job
        await asyncio.sleep(1.0)  # a command would have been retried to the drone by now
        assert drone.commands == []
        async with client.get("/api/mission", headers=auth) as resp:
            assert await resp.json() == before
    finally:
        stop.set()
        await flying
        drone.close()
        stranger.close()


async def test_a_push_only_mirror_answers_nobody_but_its_gcs(
        tmp_path: Any, aiohttp_client: Any) -> None:
    gcs = _udp("127.0.0.1")
    gcs_port = gcs.getsockname()[1]
    client = await aiohttp_client(create_app(
        _config(tmp_path, mavlink_out=f"127.0.0.1:{gcs_port}"), token=TOKEN))
    drone = FakeDrone("drone4", fleet_id=5, key=KEY, ground=client.server.app[LINK].local_addr)
    await drone.open()
    stop = asyncio.Event()
    flying = asyncio.create_task(_fly(drone, stop))
    stranger = _udp("127.0.0.2")
    me = mavlink.MAVLink(None, srcSystem=250, srcComponent=190)
    loop = asyncio.get_running_loop()
    try:
        async with asyncio.timeout(10):
            _, mirror_addr = await loop.sock_recvfrom(gcs, 4096)  # the pushed stream's source
        for _ in range(5):
            stranger.sendto(mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3).pack(me),
                            ("127.0.0.1", mirror_addr[1]))
            stranger.sendto(mavlink.MAVLink_command_long_message(
                4, 1, MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0).pack(me),
                ("127.0.0.1", mirror_addr[1]))
            await asyncio.sleep(0.2)
        assert await _receive(stranger, 2.0) == []
        pushed = await _receive(gcs, 1.5)  # the GCS still gets drone4 (system id 4)
        assert "HEARTBEAT" in {m.get_type() for m in pushed if m.get_srcSystem() == 4}
    finally:
        stop.set()
        await flying
        drone.close()
        stranger.close()
        gcs.close()


@pytest.mark.parametrize("listen", ["0.0.0.0:14551", "[::]:14551"])
def test_a_wildcard_listen_address_is_warned_about(
        listen: str, caplog: pytest.LogCaptureFixture) -> None:
    config = GroundConfig(fleet_key=KEY, command_key=TEST_COMMAND_KEY, mavlink_listen=listen)
    with caplog.at_level(logging.WARNING):
        _warn_every_interface(config)
    assert [r.getMessage()[:len(listen) + 37] for r in caplog.records] == [
        f"mavlink_listen is {listen!r}: every host that"]
    caplog.clear()
    _warn_every_interface(GroundConfig(fleet_key=KEY, command_key=TEST_COMMAND_KEY,
                                       mavlink_listen="127.0.0.1:14551"))
    assert caplog.records == []
