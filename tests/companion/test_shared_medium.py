"""The shared medium (companion.transport): one datagram reaches every fleet member.

Real sockets on loopback: two drones' transports and a ground listener all hear a message
sent once with ``shared=True``; a drone skips its own echo; unicast stays the default.
"""

from __future__ import annotations

import asyncio
import socket
import time

import pytest

from companion.protocol import Decoder, Encoder, MessageReassembled
from companion.transport import SharedMedium, UdpTransport, open_medium_socket, parse_medium
from tests.keys import TEST_FLEET_KEY
from utility_specs.errors import SpecError
from utility_specs.message import Message
from utility_specs.spec import parse_spec

FLEET = 9


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_parse_medium() -> None:
    assert parse_medium("broadcast:127.255.255.255:14700") == SharedMedium(
        kind="broadcast", address="127.255.255.255", port=14700)
    m = parse_medium("multicast:239.255.42.99:14700:127.0.0.1")
    assert (m.kind, m.address, m.port, m.interface) == ("multicast", "239.255.42.99", 14700,
                                                        "127.0.0.1")
    for bad in ("broadcast:1.2.3.4", "anycast:1.2.3.4:5", "broadcast:1.2.3:5",
                "broadcast:1.2.3.4:0", "broadcast:1.2.3.4:5:1.1.1.1",
                "multicast:10.1.2.3:5", "multicast:239.1.1.1:5:nowhere"):
        with pytest.raises(ValueError):
            parse_medium(bad)


def transport(drone: str, medium: SharedMedium, ground: tuple[str, int],
              heard: list[MessageReassembled]) -> UdpTransport:
    def on_event(event: object) -> None:
        if isinstance(event, MessageReassembled):
            heard.append(event)

    return UdpTransport(encoder=Encoder(FLEET, drone, TEST_FLEET_KEY),
                        decoder=Decoder(FLEET, TEST_FLEET_KEY, local_id=drone),
                        remote_addr=ground, local_addr=("127.0.0.1", 0), on_event=on_event,
                        medium=medium)


@pytest.mark.parametrize("text", ["broadcast:127.255.255.255:{port}",
                                  "multicast:239.255.42.99:{port}:127.0.0.1"])
async def test_one_datagram_reaches_every_member(text: str) -> None:
    medium = parse_medium(text.format(port=free_udp_port()))
    ground_sock = open_medium_socket(medium)  # the ground station's medium listener
    unicast = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    unicast.bind(("127.0.0.1", 0))
    unicast.setblocking(False)
    heard1: list[MessageReassembled] = []
    heard2: list[MessageReassembled] = []
    d1 = transport("drone1", medium, unicast.getsockname(), heard1)
    d2 = transport("drone2", medium, unicast.getsockname(), heard2)
    tasks = [asyncio.create_task(d.run()) for d in (d1, d2)]
    loop = asyncio.get_running_loop()
    try:
        await d1.wait_started()
        await d2.wait_started()
        position = Message(sender="drone1", seq=1, type="position", t_gen=time.time(), size=30,
                           data={"lat_deg": 47.0, "lon_deg": 8.0})
        assert d1.send_message(position, b"", shared=True) == 1
        async with asyncio.timeout(5):
            while not heard2:
                await asyncio.sleep(0.01)
            data, addr = await loop.sock_recvfrom(ground_sock, 2048)
        assert heard2[0].message.sender == "drone1"
        assert heard2[0].message.data["lat_deg"] == 47.0
        assert addr == d1.local_address  # replies go to the sender's own socket
        ground = Decoder(FLEET, TEST_FLEET_KEY, local_id="gs")
        ground.receive_datagram(data, addr, time.time())
        event = ground.next_event()
        assert isinstance(event, MessageReassembled) and event.message.seq == 1
        await asyncio.sleep(0.1)
        assert heard1 == [] and d1.counters["medium_own_echo"] == 1
        assert d1.counters["medium_sent"] == 1
        # unicast stays the default: only the ground's own socket gets it
        battery = Message(sender="drone1", seq=2, type="battery", t_gen=time.time(), size=20,
                          data={"level": 0.5})
        d1.send_message(battery, b"")
        async with asyncio.timeout(5):
            await loop.sock_recvfrom(unicast, 2048)
        await asyncio.sleep(0.1)
        assert len(heard2) == 1
    finally:
        for d in (d1, d2):
            d.stop()
        await asyncio.gather(*tasks)
        ground_sock.close()
        unicast.close()


def test_spec_receivers_field() -> None:
    base = {"utility": "battery", "aggregation": "max", "params": {"depletion_rate": 0.01}}
    spec = parse_spec({"types": {"battery": base,
                                 "position": {**base, "receivers": ["peers"]},
                                 "status": {**base, "receivers": ["ground", "peers"]}}})
    assert spec["battery"].receivers == ("ground",) and not spec["battery"].for_peers
    assert spec["position"].receivers == ("peers",) and spec["position"].for_peers
    assert spec["status"].receivers == ("ground", "peers")
    for bad in ([], ["ground", "ground"], ["everyone"], "peers", [1]):
        with pytest.raises(SpecError, match="receivers"):
            parse_spec({"types": {"battery": {**base, "receivers": bad}}}, source="m.toml")


async def test_ground_station_hears_the_medium(tmp_path, aiohttp_client) -> None:
    """`shared_medium` on the station: a drone's datagram sent once to the medium is stored,
    and the station still answers the drone's own unicast address."""
    from ground_station.app import create_app
    from ground_station.config import GroundConfig
    from ground_station.keys import LINK, STORAGE
    from tests.keys import TEST_COMMAND_KEY

    text = f"broadcast:127.255.255.255:{free_udp_port()}"
    config = GroundConfig(fleet_id=FLEET, fleet_key=TEST_FLEET_KEY,
                          command_key=TEST_COMMAND_KEY, data_dir=tmp_path / "gs", mission="m",
                          udp_port=0, report_interval_s=0.05, shared_medium=text)
    client = await aiohttp_client(create_app(config, token="t" * 24))
    link = client.server.app[LINK]
    heard: list[MessageReassembled] = []
    drone = transport("drone5", parse_medium(text), link.local_addr, heard)
    task = asyncio.create_task(drone.run())
    try:
        await drone.wait_started()
        battery = Message(sender="drone5", seq=3, type="battery", t_gen=time.time(), size=20,
                          data={"level": 0.7})
        assert drone.send_message(battery, b"", shared=True) == 1
        async with asyncio.timeout(5):
            while link.counters["messages"] < 1:
                await asyncio.sleep(0.01)
        assert link.fleet.drones["drone5"].battery == 0.7
        assert link.fleet.drones["drone5"].addr == drone.local_address  # replies go home
        await client.server.app[STORAGE].flush()
    finally:
        drone.stop()
        await task
