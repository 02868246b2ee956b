"""Peers report what they heard (issue 15): a drone's receiver report on the shared medium
reaches the sender, whose optimiser then knows what that peer holds and whose goodput
constraint gets the medium's link samples. Real sockets on loopback."""

from __future__ import annotations

import asyncio
import time
from dataclasses import replace

from companion.middleware.constraint import ConstantConstraint
from companion.middleware.middleware import Middleware, MiddlewareConfig
from companion.middleware.reports import ReceiverReport
from companion.peers import PeerReporter, PeerServices, PeersSettings
from companion.protocol import Decoder, Encoder, MessageReassembled, ReportReceived
from companion.protocol.records import Report
from companion.transport import UdpTransport, parse_medium
from tests.companion.test_shared_medium import FLEET, free_udp_port
from tests.keys import TEST_FLEET_KEY
from utility_specs.message import Message
from utility_specs.spec import parse_spec

SPEC = parse_spec({"types": {"position": {
    "utility": "position", "aggregation": "max", "per_sender": True, "markovian": True,
    "params": {"v_max": 15.0, "area": 1.0e6}, "receivers": ["ground", "peers"]}}})


def position(sender: str, seq: int, t: float) -> Message:
    return Message(sender=sender, seq=seq, type="position", t_gen=t, size=30, t_sent=t,
                   data={"lat_deg": 47.0, "lon_deg": 8.0})


def test_reporter_collects_peer_messages_once_per_report() -> None:
    reporter = PeerReporter("drone2")
    assert reporter.take() is None
    reporter.on_message(position("drone1", 4, 10.0), t_rcv=10.02)
    reporter.on_message(position("drone2", 1, 10.0), t_rcv=10.0)  # our own: not reported
    report = reporter.take()
    assert report is not None
    assert [(e.sender, e.seq, e.t_rcv) for e in report.entries] == [("drone1", 4, 10.02)]
    assert [(c.sender, c.t_sent, c.t_rcv) for c in report.echoes] == [("drone1", 10.0, 10.02)]
    assert reporter.take() is None


async def test_a_peers_report_reaches_the_sender_and_its_optimiser() -> None:
    medium_text = f"broadcast:127.255.255.255:{free_udp_port()}"
    medium = parse_medium(medium_text)
    reports: list[ReportReceived] = []
    learned: list[tuple[Report, float]] = []
    peers2: PeerServices | None = None

    def on_event1(event: object) -> None:
        if isinstance(event, ReportReceived):
            reports.append(event)

    def on_event2(event: object) -> None:
        assert peers2 is not None
        peers2.on_event(event)

    def make(drone: str, on_event) -> UdpTransport:  # type: ignore[no-untyped-def]
        return UdpTransport(encoder=Encoder(FLEET, drone, TEST_FLEET_KEY),
                            decoder=Decoder(FLEET, TEST_FLEET_KEY, local_id=drone),
                            remote_addr=("127.0.0.1", 9), local_addr=("127.0.0.1", 0),
                            on_event=on_event, medium=medium)

    d1, d2 = make("drone1", on_event1), make("drone2", on_event2)
    peers2 = PeerServices(PeersSettings(medium=medium_text), own_id="drone2", clock=time.time,
                          peer_types=frozenset({"position"}), send_report=d2.send_report_shared,
                          learn=lambda report, now: learned.append((report, now)),
                          report_interval_s=0.05)
    tasks = [asyncio.create_task(d.run()) for d in (d1, d2)]
    tasks.append(asyncio.create_task(peers2.run()))
    try:
        await d1.wait_started()
        await d2.wait_started()
        t = time.time()
        d1.send_message(position("drone1", 1, t), b"", t, shared=True)
        async with asyncio.timeout(5):
            while not reports:
                await asyncio.sleep(0.01)
    finally:
        peers2.stop()
        for d in (d1, d2):
            d.stop()
        await asyncio.gather(*tasks)
    event = reports[0]
    assert event.reporter == "drone2"
    assert [(e.sender, e.seq) for e in event.report.entries] == [("drone1", 1)]
    assert d2.counters["medium_reports_sent"] >= 1
    # drone2's own optimiser learned the same delivery
    assert [(e.sender, e.seq) for e in learned[0][0].entries] == [("drone1", 1)]
    # drone1's optimiser: drone2 holds its position; the constraint got a link sample
    mw = Middleware(MiddlewareConfig(spec=SPEC, agent="drone1"),
                    constraint=ConstantConstraint(limit_bytes_per_s=1e4))
    learned_here = mw.on_report(ReceiverReport.from_event(event, receiver="drone2"),
                                event.t_rcv)
    assert learned_here.delivered == 1 and learned_here.link.link_samples == 1
    assert mw.knowledge.peers_of("drone1") == ["drone2"]
    view = mw.knowledge.view(position("drone1", 2, t + 1), now=t + 1, horizon_s=2.0,
                             max_items=16, window_s=1.0)
    ground, peer = view.receivers[("position", "drone1")]
    assert ground is not None and peer is not None
    assert peer.message.seq == 1 and peer.rcv_t == event.report.entries[0].t_rcv


def test_what_a_drone_hears_reaches_its_optimiser_at_once() -> None:
    """Not a report period later: until then the peer's send would be neither in the
    optimiser's window nor in its in-flight estimate (which spans only the link latency)."""
    learned: list[tuple[Report, float]] = []
    sent: list[Report] = []
    services = PeerServices(PeersSettings(medium="broadcast:127.255.255.255:14799"),
                            own_id="drone2", clock=lambda: 100.0,
                            peer_types=frozenset({"position"}),
                            send_report=lambda report, now: sent.append(report) or 1,
                            learn=lambda report, now: learned.append((report, now)),
                            report_interval_s=3600.0)
    heard = position("drone1", 3, 99.9)
    services.on_event(MessageReassembled(message=replace(heard, t_rcv=99.95), payload=b"",
                                         addr=("127.0.0.1", 9), t_rcv=99.95, fragments=1))
    assert [([(e.sender, e.seq, e.t_rcv) for e in r.entries], now) for r, now in learned] \
        == [([("drone1", 3, 99.95)], 100.0)]
    assert not sent  # the report to the peers still waits for its period
    assert services.report_now()
    assert [(e.sender, e.seq) for e in sent[0].entries] == [("drone1", 3)]
    assert len(learned) == 1  # the report does not teach the optimiser a second time
