"""A message the transport refuses whole (the pacer's backlog is full, the link is busy) is
logged and counted as not sent, not as sent (it never reached the radio)."""

from __future__ import annotations

import asyncio
import json
import time
from pathlib import Path

from companion.config import parse_config
from companion.dispatch import COUNTERS, Dispatcher
from companion.middleware.decider import Decision
from companion.mission import MissionWindow
from companion.mission_log import MissionLogWriter
from utility_specs.message import Message


class SendAll:
    def decide(self, message: Message, now: float) -> Decision:
        return Decision(send=True, reason="test")

    def get_timer(self) -> float | None:
        return None


async def test_a_refused_send_is_not_counted_as_sent(tmp_path: Path) -> None:
    accepted = iter([27, 0])  # the first message goes, the second is refused whole
    log_path = tmp_path / "mission_log.jsonl"
    counters = dict.fromkeys(COUNTERS, 0)
    mission_log = MissionLogWriter(log_path)
    dispatcher = Dispatcher(parse_config({"drone": {"id": "d1"}}), decider=SendAll(),  # type: ignore[arg-type]
                            clock=time.time, send_message=lambda m, p, t: next(accepted),
                            mission_log=mission_log,
                            mission=MissionWindow("running"), counters=counters)
    stopping = asyncio.Event()
    dispatcher.bind(stopping)
    try:
        for seq in (1, 2):
            message = Message(sender="d1", seq=seq, type="image", t_gen=time.time(), size=30_000)
            assert await dispatcher.submit(message) is (seq == 1)
    finally:
        stopping.set()
        dispatcher.close()
        mission_log.close()
    assert counters["sent"] == 1 and counters["send_errors"] == 1
    assert dispatcher.sent_by_type == {"image": 1}
    records = [json.loads(line) for line in log_path.read_text().splitlines()]
    by_seq = {r["seq"]: r for r in records if "seq" in r}
    assert by_seq[1]["t_sent"] is not None
    assert by_seq[2]["t_sent"] is None
    assert by_seq[2]["decision"]["error"] == "the transport refused it (link queue full)"
