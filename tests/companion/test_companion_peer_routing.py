"""The companion app with a shared medium (issue 15): a peer's receiver report reaches the
decider as that peer's, the ground's as the ground's; what the drone hears from peers goes
out as its own receiver report and to its own decider; its status carries its peers' ages."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path
from typing import Any

from companion.app import CompanionApp
from companion.config import parse_config
from companion.protocol import MessageReassembled, ReportReceived
from companion.protocol.records import Report, ReportEntry
from tests.companion.test_companion_app import (
    FakeDecider,
    FakeTransport,
    RedThenPlain,
    _until,
)
from utility_specs.message import Message


class MediumTransport(FakeTransport):
    def __init__(self, on_event: Any) -> None:
        super().__init__(on_event)
        self.reports: list[Report] = []

    def send_message(self, message: Message, payload: bytes, now: float, *,
                     shared: bool = False) -> int:
        return super().send_message(message, payload, now)

    def send_report_shared(self, report: Report, now: float) -> int:
        self.reports.append(report)
        return 1


def report_from(reporter: str, t: float) -> ReportReceived:
    entry = ReportEntry(sender="d1", seq=1, type="position", t_gen=t - 1, t_sent=t - 1,
                        t_rcv=t - 0.9, size=30)
    return ReportReceived(report=Report(entries=(entry,)), reporter=reporter, report_number=1,
                          part_index=0, part_count=1, t_sent=t, t_rcv=t,
                          addr=("127.0.0.1", 9))


async def test_reports_are_routed_by_who_sent_them(vehicle: Any, tmp_path: Path) -> None:
    config = parse_config({
        "drone": {"id": "d1"},
        "mavlink": {"url": f"udpout:127.0.0.1:{vehicle.port}", "heartbeat_timeout_s": 2.0},
        "camera": {"enabled": False},
        "mission": {"log": str(tmp_path / "mission.jsonl"), "spec": "builtin:peer_sharing"},
        "telemetry": {"status_period_s": 0.3},
        "peers": {"medium": "broadcast:127.255.255.255:14799"},
    })
    decider = FakeDecider()
    transports: list[MediumTransport] = []

    def factory(on_event: Any) -> MediumTransport:
        transports.append(MediumTransport(on_event))
        return transports[-1]

    app = CompanionApp(config, decider=decider, transport_factory=factory, clock=time.time,
                       frame_source=RedThenPlain())
    task = asyncio.create_task(app.run())
    try:
        await _until(lambda: bool(transports))
        t = time.time()
        heard = Message(sender="d2", seq=7, type="position", t_gen=t - 0.2, size=30,
                        receiver="d1", t_sent=t - 0.2, t_rcv=t,
                        data={"lat_deg": 47.0, "lon_deg": 8.0})
        on_event = transports[0].on_event
        on_event(MessageReassembled(message=heard, payload=b"", addr=("127.0.0.1", 9),
                                    t_rcv=t, fragments=1))
        on_event(report_from("d2", t))  # a peer heard on the medium
        on_event(report_from("gs", t))  # the ground station
        await _until(lambda: transports[0].reports and len(decider.reports) >= 3)
        await _until(lambda: any("peers" in m.data for m, _ in transports[0].sent
                                 if m.type == "status"))
    finally:
        app.stop()
        await asyncio.wait_for(task, 10)
    receivers = [r.receiver for r in decider.reports]
    # what d1 heard itself reaches its own optimiser at once, then the two reports
    assert receivers == ["d1", "d2", "ground"]
    own = next(r for r in decider.reports if r.receiver == "d1")
    assert [(e.sender, e.seq) for e in own.entries] == [("d2", 7)]
    sent = transports[0].reports[0]
    assert [(e.sender, e.seq) for e in sent.entries] == [("d2", 7)]
    assert [c.sender for c in sent.echoes] == ["d2"]
    status = next(m for m, _ in transports[0].sent if m.type == "status" and "peers" in m.data)
    assert set(status.data["peers"]) == {"d2"}
