"""A drone's own status period decides when the station calls it lost.

Before, the station judged every drone by its ``link_lost_s`` (3 s): a drone configured with
``status_period_s = 5`` (sending nothing else before it has a position) was "link lost" and
"link back" every few seconds on a healthy link, and its mode and armed state were marked
stale between two statuses.
"""

from __future__ import annotations

import asyncio
import time

import pytest

from ground_station.drone_state import MAX_STATUS_PERIOD_S
from ground_station.fleet import FleetView
from tests.publisher_dispatcher import RecordingDispatcher
from utility_specs.message import Message

T0 = 1_700_000_000.0


def status(t: float, seq: int, **data: object) -> Message:
    return Message(sender="d1", seq=seq, type="status", t_gen=t, t_sent=t, t_rcv=t, size=200,
                   data={"mode": "GUIDED", "armed": True, **data}, receiver="gs")


def lost_alerts(fv: FleetView) -> list[str]:
    return [a.text for a in fv.take_new_alerts() if a.kind == "link"]


def test_a_drone_that_says_it_sends_a_status_every_5_s_is_lost_after_12_5_s() -> None:
    fv = FleetView(high_utility=None, link_lost_s=3.0)
    for k in range(4):  # a status every 5 s, for 15 s: never lost, never stale
        fv.on_message(status(T0 + 5.0 * k, k, status_period_s=5.0), now=T0 + 5.0 * k)
        for dt in (1.0, 3.5, 4.9):
            fv.tick(now=T0 + 5.0 * k + dt)
            assert fv.drone_json(fv.drones["d1"], now=T0 + 5.0 * k + dt)["stale"] == []
    assert lost_alerts(fv) == []
    last = T0 + 15.0
    fv.tick(now=last + 12.4)
    assert lost_alerts(fv) == []
    fv.tick(now=last + 12.6)
    assert [t.split(":")[0] for t in lost_alerts(fv)] == ["link lost"]
    tile = fv.drone_json(fv.drones["d1"], now=last + 12.6)
    assert tile["link_lost"] is True and {"mode", "armed"} <= set(tile["stale"])


def test_without_a_period_and_with_a_short_one_link_lost_s_decides() -> None:
    for data in ({}, {"status_period_s": 0.5}, {"status_period_s": 1.0}):
        fv = FleetView(high_utility=None, link_lost_s=3.0)
        fv.on_message(status(T0, 1, **data), now=T0)
        fv.tick(now=T0 + 2.9)
        assert lost_alerts(fv) == [], data
        fv.tick(now=T0 + 3.1)
        assert len(lost_alerts(fv)) == 1, data
        assert fv.drone_json(fv.drones["d1"], now=T0 + 12.1)["stale"] != [], data


@pytest.mark.parametrize("period", [0.0, -5.0, float("nan"), float("inf"), 1e9, "5", True])
def test_a_period_out_of_range_is_not_taken(period: object) -> None:
    fv = FleetView(high_utility=None, link_lost_s=3.0)
    fv.on_message(status(T0, 1, status_period_s=period), now=T0)
    fv.tick(now=T0 + 3.1)
    assert len(lost_alerts(fv)) == 1


def test_the_longest_period_taken_still_loses_a_silent_drone() -> None:
    fv = FleetView(high_utility=None, link_lost_s=3.0)
    fv.on_message(status(T0, 1, status_period_s=MAX_STATUS_PERIOD_S), now=T0)
    fv.tick(now=T0 + 2.5 * MAX_STATUS_PERIOD_S - 0.1)
    assert lost_alerts(fv) == []
    fv.tick(now=T0 + 2.5 * MAX_STATUS_PERIOD_S + 0.1)
    assert len(lost_alerts(fv)) == 1


@pytest.mark.parametrize(("state", "expected"), [("running", 5.0), ("idle", 1.0),
                                                 ("ended", 1.0)])
async def test_the_companion_says_the_period_its_next_status_keeps(
        state: str, expected: float) -> None:
    """Outside the mission window a status goes every second whatever the setting."""
    from companion.config import TelemetryConfig
    from companion.mission import MissionWindow
    from companion.publisher import TelemetryPublisher
    from companion.telemetry import TelemetryState

    dispatcher = RecordingDispatcher()
    publisher = TelemetryPublisher(TelemetryConfig(status_period_s=5.0),
                                   telemetry=TelemetryState(),
                                   dispatcher=dispatcher,  # type: ignore[arg-type]
                                   mission=MissionWindow(state=state), clock=time.time)
    task = asyncio.create_task(publisher.run())
    try:
        for _ in range(100):
            await asyncio.sleep(0.01)
            if dispatcher.statuses:
                break
    finally:
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
    assert dispatcher.statuses and dispatcher.statuses[0]["status_period_s"] == expected


def test_the_mavlink_mirror_keeps_a_slow_drone_alive_between_its_statuses() -> None:
    """QGroundControl, fed by the mirror, showed the drone lost between two 5 s statuses."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    from ground_station.mavlink_mirror import MavlinkMirror

    def heartbeats(m: MavlinkMirror) -> int:
        parser = mavlink.MAVLink(None)
        frames = [f for d, _ in m.datagrams_to_send() for f in parser.parse_buffer(d) or []]
        return sum(f.get_type() == "HEARTBEAT" for f in frames)

    slow = MavlinkMirror(now=100.0)
    usual = MavlinkMirror(now=100.0)
    slow.on_data("d1", {"mode": "GUIDED", "armed": True, "status_period_s": 5.0}, now=100.0)
    usual.on_data("d1", {"mode": "GUIDED", "armed": True}, now=100.0)
    heartbeats(slow), heartbeats(usual)
    for t in (104.5, 112.0):
        slow.handle_timer(t)
        usual.handle_timer(t)
        assert heartbeats(slow) >= 1 and heartbeats(usual) == 0, t
    slow.handle_timer(113.0)
    assert heartbeats(slow) == 0  # 2.5 periods of silence: lost there too
