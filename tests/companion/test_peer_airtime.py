"""Receiver reports on the shared medium count in the goodput budget (issue 15): the bytes of
the reports a drone sends and of those it hears from peers come off the window's budget, so
the optimiser leaves them their air time (companion/peer_airtime.py)."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path
from typing import Any

import numpy as np

from companion.app import CompanionApp
from companion.config import parse_config
from companion.middleware.constraint import ConstantConstraint
from companion.middleware.constraints.adaptive import AdaptiveConstraint
from companion.middleware.middleware import Middleware, MiddlewareConfig
from companion.peer_airtime import CountingReports, ReportTraffic, report_wire_bytes
from companion.peers import PeerServices, PeersSettings
from companion.protocol import Decoder, Encoder, MessageReassembled
from companion.protocol.records import ClockEcho, Report, ReportEntry
from companion.transport import UdpTransport, parse_medium
from tests.companion.test_companion_app import FakeDecider, RedThenPlain, _until
from tests.companion.test_companion_peer_routing import MediumTransport, report_from
from tests.companion.test_peer_reports import SPEC, position
from tests.companion.test_shared_medium import FLEET, free_udp_port
from tests.keys import TEST_FLEET_KEY
from utility_specs.message import Message


def a_report(n: int, t: float) -> Report:
    entries = tuple(ReportEntry(sender="drone1", seq=i, type="position", t_gen=t, t_sent=t,
                                t_rcv=t + 0.01, size=30) for i in range(n))
    return Report(entries=entries, echoes=(ClockEcho(sender="drone1", t_sent=t, t_rcv=t + 0.01),))


def test_wire_bytes_are_the_encoded_datagrams() -> None:
    t = 1_700_000_000.25
    for n in (0, 1, 40, 400):  # 400 entries take several datagrams
        report = a_report(n, t)
        real = Encoder(FLEET, "drone2", TEST_FLEET_KEY).encode_report(report, t + 0.3)
        assert report_wire_bytes(report, sender="drone2") == sum(len(d) for d in real)
    assert len(Encoder(FLEET, "drone2", TEST_FLEET_KEY).encode_report(a_report(400, t), t)) > 1


def test_the_reports_of_the_last_window_come_off_the_budget() -> None:
    traffic = ReportTraffic()
    constraint = CountingReports(ConstantConstraint(limit_bytes_per_s=1000.0, window_s=1.0),
                                 traffic)
    assert constraint.budget_bytes(now=10.0) == 1000.0
    traffic.add(10.0, 300)
    traffic.add(10.25, 200)
    assert constraint.budget_bytes(now=10.25) == 500.0
    assert constraint.budget_bytes(now=11.1) == 800.0  # the first report left the window
    assert constraint.budget_bytes(now=11.3) == 1000.0
    traffic.add(20.0, 5000)
    assert constraint.budget_bytes(now=20.0) == 0.0  # never negative
    # ξ, the window and the live parameters stay the wrapped constraint's
    assert constraint.limit_bytes_per_s(now=20.0) == 1000.0
    assert constraint.window_s == 1.0
    assert constraint.check_params({"limit_bytes_per_s": 2000}) == {"limit_bytes_per_s": 2000.0}
    constraint.apply_params({"limit_bytes_per_s": 2000.0})
    assert constraint.inner.limit_bytes_per_s(now=0.0) == 2000.0


def _decide_with_reports(report_bytes: int) -> bool:
    traffic = ReportTraffic()
    mw = Middleware(MiddlewareConfig(spec=SPEC, agent="drone1", max_iterations=50),
                    constraint=CountingReports(ConstantConstraint(limit_bytes_per_s=1000.0,
                                                                  window_s=1.0), traffic),
                    rng=np.random.default_rng(0))
    if report_bytes:
        traffic.add(9.9, report_bytes)
    message = Message(sender="drone1", seq=0, type="position", t_gen=10.0, size=400,
                      data={"lat_deg": 47.0, "lon_deg": 8.0})
    return mw.decide(message, 10.0).send


def test_the_optimiser_leaves_the_reports_their_air_time() -> None:
    assert _decide_with_reports(0)  # 400 B fit in 1000
    assert _decide_with_reports(500)  # 400 + 500 still fit
    assert not _decide_with_reports(700)  # 400 + 700 do not: the position waits


async def test_sent_and_heard_reports_are_counted_at_their_wire_size() -> None:
    """Real sockets: drone2 reports what it heard from drone1; drone1 hears that report on
    the medium. Both count exactly the bytes drone2 put on the medium."""
    medium_text = f"broadcast:127.255.255.255:{free_udp_port()}"
    medium = parse_medium(medium_text)
    services: dict[str, PeerServices] = {}

    def make(drone: str) -> UdpTransport:
        return UdpTransport(encoder=Encoder(FLEET, drone, TEST_FLEET_KEY),
                            decoder=Decoder(FLEET, TEST_FLEET_KEY, local_id=drone),
                            remote_addr=("127.0.0.1", 9), local_addr=("127.0.0.1", 0),
                            on_event=lambda e: services[drone].on_event(e), medium=medium)

    d1, d2 = make("drone1"), make("drone2")
    for drone, transport in (("drone1", d1), ("drone2", d2)):
        services[drone] = PeerServices(PeersSettings(medium=medium_text), own_id=drone,
                                       clock=time.time, peer_types=frozenset({"position"}),
                                       send_report=transport.send_report_shared,
                                       report_interval_s=3600.0)
    tasks = [asyncio.create_task(d.run()) for d in (d1, d2)]
    try:
        await d1.wait_started()
        await d2.wait_started()
        t = time.time()
        d2.send_message(position("drone2", 1, t), b"", t, shared=True)  # drone1 knows drone2
        d1.send_message(position("drone1", 1, t), b"", t, shared=True)
        async with asyncio.timeout(5):
            while not (services["drone1"].table.peers and services["drone2"].table.peers):
                await asyncio.sleep(0.01)
        before = d2.counters["bytes_sent"]
        assert services["drone2"].report_now()
        sent = d2.counters["bytes_sent"] - before
        async with asyncio.timeout(5):
            while not services["drone1"].report_traffic.counters["reports"]:
                await asyncio.sleep(0.01)
    finally:
        for d in (d1, d2):
            d.stop()
        await asyncio.gather(*tasks)
    assert sent > 0
    assert services["drone2"].report_traffic.counters == {"reports": 1, "bytes": sent}
    assert services["drone1"].report_traffic.counters == {"reports": 1, "bytes": sent}


class DeciderWithBudget(FakeDecider):
    def __init__(self) -> None:
        super().__init__()
        self.constraint = ConstantConstraint(limit_bytes_per_s=5000.0, window_s=30.0)


async def test_the_companion_counts_reports_in_its_deciders_budget(vehicle: Any,
                                                                   tmp_path: Path) -> None:
    config = parse_config({
        "drone": {"id": "d1"},
        "mavlink": {"url": f"udpout:127.0.0.1:{vehicle.port}", "heartbeat_timeout_s": 2.0},
        "camera": {"enabled": False},
        "mission": {"log": str(tmp_path / "mission.jsonl"), "spec": "builtin:peer_sharing"},
        "peers": {"medium": "broadcast:127.255.255.255:14799"},
    })
    decider = DeciderWithBudget()
    transports: list[MediumTransport] = []

    def factory(on_event: Any) -> MediumTransport:
        transports.append(MediumTransport(on_event))
        return transports[-1]

    app = CompanionApp(config, decider=decider, transport_factory=factory, clock=time.time,
                       frame_source=RedThenPlain())
    assert isinstance(decider.constraint, CountingReports)
    task = asyncio.create_task(app.run())
    try:
        await _until(lambda: bool(transports))
        t = time.time()
        heard = Message(sender="d2", seq=7, type="position", t_gen=t - 0.2, size=30,
                        receiver="d1", t_sent=t - 0.2, t_rcv=t,
                        data={"lat_deg": 47.0, "lon_deg": 8.0})
        transports[0].on_event(MessageReassembled(message=heard, payload=b"",
                                                  addr=("127.0.0.1", 9), t_rcv=t, fragments=1))
        peer_report = report_from("d2", t)
        transports[0].on_event(peer_report)
        transports[0].on_event(report_from("gs", t))  # the ground's: not on the medium
        await _until(lambda: bool(transports[0].reports))
        now = time.time()
        budget = decider.constraint.budget_bytes(now=now)
    finally:
        app.stop()
        await asyncio.wait_for(task, 10)
    expected = report_wire_bytes(peer_report.report, sender="d2") + sum(
        report_wire_bytes(r, sender="d1") for r in transports[0].reports)
    assert budget == 5000.0 * 30.0 - expected


def test_without_a_medium_nothing_is_wrapped() -> None:
    decider = DeciderWithBudget()
    services = PeerServices(PeersSettings(), own_id="d1", clock=time.time)
    assert not services.count_reports_in(decider)
    assert isinstance(decider.constraint, ConstantConstraint)


def test_a_link_learning_constraint_is_not_charged_twice() -> None:
    """Adaptive and AIMD learn ξ from the medium, where the reports already are load."""
    decider = DeciderWithBudget()
    decider.constraint = AdaptiveConstraint(window_s=1.0)
    services = PeerServices(PeersSettings(medium="broadcast:127.255.255.255:14799"),
                            own_id="d1", clock=time.time, send_report=lambda report, now: None)
    assert not services.count_reports_in(decider)
    assert isinstance(decider.constraint, AdaptiveConstraint)
