"""The ground station's transport seam (issue 14): the link speaks the fleet protocol over any
:class:`~ground_station.transport.GroundTransport`; the address type is the transport's.

A radio-like transport whose addresses are ``("radio", channel)`` (no host, no port) carries
an image in and the receiver report out: the image is stored, and the report goes back to
the address the image came from, reporting that image delivered.
"""

from __future__ import annotations

import ast
import asyncio
import time
from collections import Counter
from collections.abc import Sequence
from pathlib import Path

from companion.protocol import Decoder, Encoder, ReportReceived
from ground_station.broadcast import Broadcaster
from ground_station.config import GroundConfig
from ground_station.fleet import FleetView
from ground_station.missions import MissionManager
from ground_station.receiver import GroundLink, tile_interval
from ground_station.store_service import StorageService
from ground_station.transport import DatagramSink
from ground_station.utility import ImageUtility
from tests.ground_station.conftest import KEY
from tests.keys import TEST_COMMAND_KEY
from utility_specs.message import Message

RadioAddress = tuple[str, int]
"""("radio", channel): what this transport calls a peer."""


class RadioTransport:
    """In-memory datagram transport: ``deliver`` plays the air, ``sent`` is what went out."""

    def __init__(self) -> None:
        self.counters: Counter[str] = Counter()
        self.sink: DatagramSink[RadioAddress] | None = None
        self.sent: list[tuple[bytes, RadioAddress]] = []
        self.closed = False

    async def open(self, sink: DatagramSink[RadioAddress]) -> RadioAddress:
        self.sink = sink
        return self.local_addr

    @property
    def local_addr(self) -> RadioAddress:
        return ("radio", 0)

    def deliver(self, datagrams: Sequence[bytes], addr: RadioAddress) -> None:
        assert self.sink is not None
        self.sink.datagrams_received([(d, addr) for d in datagrams])

    def send(self, datagram: bytes, addr: RadioAddress) -> bool:
        self.sent.append((datagram, addr))
        self.counters["datagrams_sent"] += 1
        return True

    def close(self) -> None:
        self.closed = True

    def stats(self) -> dict[str, int]:
        return {"radio_channels": 1}


async def test_an_image_over_another_transport_is_stored_and_reported(tmp_path: Path) -> None:
    config = GroundConfig(fleet_id=7, fleet_key=KEY, command_key=TEST_COMMAND_KEY,
                          data_dir=tmp_path / "gs", mission="m1", report_interval_s=0.05,
                          fsync=False)
    radio = RadioTransport()
    link: GroundLink | None = None

    def on_batch(items: object, result: object) -> None:
        assert link is not None
        link.on_storage_batch(items, result)  # type: ignore[arg-type]

    storage = StorageService(config.data_dir, clock=time.time, fsync=False, on_batch=on_batch)
    await storage.open()
    link = GroundLink(config=config, clock=time.time,
                      fleet=FleetView(high_utility=2.0, link_lost_s=5.0),
                      missions=MissionManager(retry_s=0.1), storage=storage,
                      broadcaster=Broadcaster(queue_size=8), image_utility=ImageUtility(),
                      latest_jpeg={}, transport=radio)
    try:
        assert await link.open() == ("radio", 0) and link.local_addr == ("radio", 0)
        drone = Encoder(7, "uav1", KEY)
        now = time.time()
        jpeg = b"\xff\xd8" + bytes(range(256)) * 12
        m = Message(sender="uav1", seq=1, type="image", t_gen=now - 0.1, size=len(jpeg),
                    data={"red": 0.5})
        radio.deliver(drone.fragment(m, jpeg, now), ("radio", 7))
        await storage.flush()
        rows = await storage.read(lambda s: s.images("m1", limit=10))
        assert [(r.sender, r.seq, r.utility) for r in rows] == [("uav1", 1, 6.0)]  # 1 + 10·0.5
        assert (config.data_dir / str(rows[0].path)).read_bytes() == jpeg
        # the report goes back over the same transport, to the address the image came from
        drone_side = Decoder(7, KEY, local_id="uav1")
        delivered: set[int] = set()
        for _ in range(100):
            for datagram, addr in radio.sent:
                assert addr == ("radio", 7)
                drone_side.receive_datagram(datagram, addr, time.time())
            radio.sent.clear()
            while (event := drone_side.next_event()) is not None:
                if isinstance(event, ReportReceived):
                    delivered |= {e.seq for e in event.report.entries if e.sender == "uav1"}
            if delivered:
                break
            await asyncio.sleep(0.02)
        assert delivered == {1}
        stats = link.stats(now=time.time())
        assert stats["radio_channels"] == 1 and stats["link"]["datagrams_sent"] >= 1
        assert link.fleet.drone_json(link.fleet.drones["uav1"], now=time.time())["addr"] == [
            "radio", 7]
    finally:
        link.close()
        await storage.close()
    assert radio.closed


def test_the_link_never_touches_a_socket() -> None:
    """The protocol logic imports no socket module and calls no socket method."""
    source = (Path(__file__).resolve().parents[2] / "ground_station" / "receiver.py").read_text()
    tree = ast.parse(source)
    imported = {alias.name for node in ast.walk(tree) if isinstance(node, ast.Import)
                for alias in node.names}
    imported |= {str(node.module) for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)}
    assert "socket" not in imported
    called = {node.attr for node in ast.walk(tree) if isinstance(node, ast.Attribute)}
    assert not called & {"sendto", "recvfrom", "recv", "setsockopt", "add_reader", "bind"}


def test_tile_pushes_per_second_stay_bounded_as_the_fleet_grows() -> None:
    """Small fleets keep the 0.25 s interval; past 12 drones the fleet-wide rate is 50/s."""
    assert tile_interval(1) == tile_interval(12) == 0.25
    assert tile_interval(50) == 1.0
    for drones in range(1, 200):
        assert drones / tile_interval(drones) <= 50.0 * (1 + 1e-12)
