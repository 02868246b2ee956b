"""Issue 13, item 3: reports and the fleet view scale with senders, not with ids ever heard.

Reports used to stop for the whole fleet once 23 senders had been heard (every echo in the
first datagram, echoes never expired); 3000 churned ids made ``/api/fleet`` 2.7 MB and 5.1 s.
"""

from __future__ import annotations

import asyncio
import dataclasses
import itertools
import socket
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.protocol import ClockEcho, Decoder, Encoder, Report, ReportReceived, Status
from companion.protocol.wire import MAX_DATAGRAM_BYTES
from ground_station.fleet import FleetView
from ground_station.keys import FLEET, LATEST_JPEG, LINK, MISSIONS
from ground_station.reports import ReportScheduler
from tests.integration.test_ground_station_udp import AUTH, KEY, make_config
from utility_specs.message import Message

T0 = 1_700_000_000.0


def long_id(i: int) -> str:
    return f"drone-{i:05d}-".ljust(32, "x")  # the longest id the wire allows


# -- sans-I/O ------------------------------------------------------------------------------
def test_echoes_rotate_so_every_sender_gets_one_every_few_reports() -> None:
    rs = ReportScheduler(interval_s=0.25, max_echoes=32, now=T0)
    for i in range(100):
        rs.on_datagram(long_id(i), t_sent=T0 - 0.1, t_rcv=T0)
    seen: list[set[str]] = []
    for k in range(1, 5):
        report = rs.due(now=T0 + 0.25 * k)
        assert report is not None and len(report.echoes) <= 32
        seen.append({e.sender for e in report.echoes})
    assert set().union(*seen) == {long_id(i) for i in range(100)}  # 4 reports cover 100
    assert all(len(a & b) == 0 for a, b in itertools.pairwise(seen))


def test_silent_senders_are_forgotten_and_the_count_is_bounded() -> None:
    rs = ReportScheduler(interval_s=0.25, echo_ttl_s=10.0, max_senders=1024, now=T0)
    for i in range(3000):  # churned ids, all within the TTL
        rs.on_datagram(f"churn{i}", t_sent=T0, t_rcv=T0 + i * 0.001)
    assert rs.sender_count == 1024
    rs.on_datagram("alive", t_sent=T0 + 14, t_rcv=T0 + 14)
    report = rs.due(now=T0 + 14)  # the newest churned id was heard at T0 + 3
    assert report is not None and [e.sender for e in report.echoes] == ["alive"]
    assert rs.sender_count == 1


@settings(max_examples=40, deadline=None)
@given(senders=st.integers(0, 300), entries=st.integers(0, 60))
def test_any_number_of_echoes_encodes_and_decodes(senders: int, entries: int) -> None:
    """Property: echoes spread over datagrams (each <= 1200 bytes); all of them arrive."""
    echoes = tuple(ClockEcho(sender=long_id(i), t_sent=T0 - i, t_rcv=T0 + 0.123456789)
                   for i in range(senders))
    from companion.protocol.records import ReportEntry

    report_entries = tuple(
        ReportEntry(sender=long_id(i), seq=i, type="image", t_gen=T0, t_sent=T0, t_rcv=T0,
                    size=30_000, data={"red": 0.5})
        for i in range(entries)
    )
    datagrams = Encoder(3, "gs", KEY).encode_report(
        Report(entries=report_entries, echoes=echoes), now=T0
    )
    assert all(len(d) <= MAX_DATAGRAM_BYTES for d in datagrams)
    decoder = Decoder(3, KEY)
    for d in datagrams:
        decoder.receive_datagram(d, ("127.0.0.1", 1), T0)
    parts = []
    while (event := decoder.next_event()) is not None:
        assert isinstance(event, ReportReceived)
        parts.append(event)
    assert [e for p in parts for e in p.report.echoes] == list(echoes)
    assert [e for p in parts for e in p.report.entries] == list(report_entries)


def test_the_fleet_view_forgets_silent_drones_and_is_bounded() -> None:
    fleet = FleetView(high_utility=5.0, link_lost_s=3.0, forget_after_s=60.0, max_drones=128)
    for i in range(3000):
        fleet.heard(f"churn{i}", now=T0 + i * 0.01)
    assert len(fleet.drones) == 128 and fleet.forgotten == 3000 - 128
    assert set(fleet.drones) == {f"churn{i}" for i in range(3000 - 128, 3000)}  # newest kept
    fleet.heard("alive", now=T0 + 100)
    fleet.tick(now=T0 + 100)
    assert list(fleet.drones) == ["alive"] and fleet.forgotten == 3000
    assert len(fleet.take_forgotten()) == 3000 and fleet.take_forgotten() == []
    assert fleet.snapshot(now=T0 + 100)["forgotten"] == 3000


def test_the_snapshot_history_shrinks_with_the_fleet_not_its_bytes() -> None:
    import json

    small = FleetView(high_utility=5.0, link_lost_s=3.0)
    large = FleetView(high_utility=5.0, link_lost_s=3.0)
    for i in range(3):
        small.heard(f"d{i}", now=T0)
    for i in range(128):
        large.heard(long_id(i), now=T0)
    for k in range(200):
        small.tick(now=T0 + k * 0.01)
        large.tick(now=T0 + k * 0.01)
    assert len(small.snapshot(now=T0 + 2)["series"]) == 120
    snapshot = large.snapshot(now=T0 + 2)
    assert 2 <= len(snapshot["series"]) < 120
    assert sum(len(p["drones"]) for p in snapshot["series"]) <= 2000
    assert len(json.dumps(snapshot)) < 300_000


# -- over real UDP -------------------------------------------------------------------------
class Listener(asyncio.DatagramProtocol):
    """A drone that only listens: decodes the reports sent to it."""

    def __init__(self, drone_id: str) -> None:
        self.decoder = Decoder(3, KEY, local_id=drone_id)
        self.reports: list[ReportReceived] = []

    def datagram_received(self, data: bytes, addr: tuple[str | Any, int]) -> None:
        self.decoder.receive_datagram(data, addr, time.time())
        while (event := self.decoder.next_event()) is not None:
            if isinstance(event, ReportReceived):
                self.reports.append(event)


async def until(predicate: Callable[[], bool], timeout: float = 10.0) -> None:
    async with asyncio.timeout(timeout):
        while not predicate():
            await asyncio.sleep(0.01)


@pytest.mark.timeout(120)
async def test_reports_keep_flowing_with_100_senders_and_3000_churned_ids(
    tmp_path: Path, aiohttp_client: Callable[..., Any], caplog: pytest.LogCaptureFixture
) -> None:
    from ground_station.app import create_app
    from tests.integration.test_ground_station_udp import TOKEN

    # the default-like report period: 100 listening drones in this process decode every report
    config = dataclasses.replace(make_config(tmp_path / "gs"), report_interval_s=0.25)
    client = await aiohttp_client(create_app(config, token=TOKEN))
    app = client.server.app
    link = app[LINK]
    loop = asyncio.get_running_loop()
    ground = link.local_addr

    # 100 drones, each on its own socket, each sends a STATUS: all are heard
    drones: list[tuple[str, Listener, asyncio.DatagramTransport, Encoder]] = []
    for i in range(100):
        name = long_id(i)
        listener = Listener(name)
        transport, _ = await loop.create_datagram_endpoint(
            lambda listener=listener: listener, local_addr=("127.0.0.1", 0))
        encoder = Encoder(3, name, KEY)
        drones.append((name, listener, transport, encoder))
        transport.sendto(encoder.encode_status(Status(state="idle"), time.time()), ground)
    await until(lambda: len(app[FLEET].drones) == 100)

    def has_echo(name: str, listener: Listener) -> bool:
        return any(e.sender == name for r in listener.reports for e in r.report.echoes)

    # every drone gets its own echo within a few reports (they rotate, 32 per report)
    await until(lambda: all(has_echo(n, lis) for n, lis, _, _ in drones))

    # 3000 ids, heard once each from one socket (a key holder churning ids)
    churn = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    churn.setblocking(False)
    for i in range(3000):
        encoder = Encoder(3, f"churn{i}", KEY)
        datagram = encoder.encode_status(Status(state="idle"), time.time())
        while True:
            try:
                churn.sendto(datagram, ground)
                break
            except BlockingIOError:
                await asyncio.sleep(0.001)
        if i % 100 == 0:
            await asyncio.sleep(0.005)  # paced: no loss in the socket buffer
    await until(lambda: link.counters["statuses"] >= 3000 + 100, timeout=30)
    # and 300 more ids send an image each: the latest JPEG kept per drone is bounded too
    for i in range(300):
        encoder = Encoder(3, f"imager{i}", KEY)
        message = Message(sender=f"imager{i}", seq=1, type="image", t_gen=time.time(),
                          size=20_000, data={"red": 0.1})
        for datagram in encoder.fragment(message, bytes(20_000), time.time()):
            churn.sendto(datagram, ground)
        await asyncio.sleep(0.002)
    await until(lambda: link.counters["images"] >= 300, timeout=30)
    await until(lambda: len(app[LATEST_JPEG]) <= 128, timeout=5)  # pruned on the next tick

    # the 100 drones keep hearing: a fresh status, then a report with their echo
    for listener in (lis for _, lis, _, _ in drones):
        listener.reports.clear()
    for _, _, transport, encoder in drones:
        transport.sendto(encoder.encode_status(Status(state="idle"), time.time()), ground)
    await until(lambda: all(has_echo(n, lis) for n, lis, _, _ in drones))

    # /api/fleet stays small and fast: bounded tiles, the rest summarised
    started = time.perf_counter()
    response = await client.get("/api/fleet", headers=AUTH)
    body = await response.read()
    elapsed = time.perf_counter() - started
    snapshot = await response.json()
    assert len(snapshot["drones"]) <= 128 and snapshot["forgotten"] >= 3400 - 128
    assert len(body) < 400_000, len(body)
    assert elapsed < 1.0, elapsed
    assert len(app[MISSIONS].drones) <= 128 + 100
    assert link.reports.sender_count <= 1024 and link.decoder.sender_count <= 256
    assert not [r for r in caplog.records if "not encodable" in r.getMessage()]
    churn.close()
    for _, _, transport, _ in drones:
        transport.close()
    print(f"/api/fleet: {len(body)} bytes in {elapsed * 1000:.0f} ms")
