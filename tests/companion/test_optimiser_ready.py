"""``optimiser_ready`` from the dispatcher through the status message to ``/api/fleet``: false
while the optimiser warms up, true once the warm-up is over however it ended (the fleet
launcher starts the mission on it)."""

from __future__ import annotations

import asyncio
import threading
import time

from companion.config import parse_config
from companion.dispatch import COUNTERS, Dispatcher
from companion.middleware.decider import Decision
from companion.mission import MissionWindow
from companion.mission_log import MissionLogWriter
from ground_station.fleet import FleetView
from utility_specs.message import Message


class Decider:
    def __init__(self, *, fail: bool = False) -> None:
        self.release = threading.Event()
        self.fail = fail

    def warm_up(self) -> None:
        self.release.wait(10.0)
        if self.fail:
            raise RuntimeError("numba: no compiler")

    def decide(self, message: Message, now: float) -> Decision:
        return Decision(send=True, reason="test")

    def get_timer(self) -> float | None:
        return None


def _dispatcher(decider: object) -> tuple[Dispatcher, asyncio.Event]:
    dispatcher = Dispatcher(parse_config({"drone": {"id": "d1"}}), decider=decider,  # type: ignore[arg-type]
                            clock=time.time, send_message=lambda m, p, t: 1,
                            mission_log=MissionLogWriter(None), mission=MissionWindow("idle"),
                            counters=dict.fromkeys(COUNTERS, 0))
    stopping = asyncio.Event()
    dispatcher.bind(stopping)
    return dispatcher, stopping


async def test_ready_only_after_the_warm_up_even_a_failed_one() -> None:
    for fail in (False, True):
        decider = Decider(fail=fail)
        dispatcher, stopping = _dispatcher(decider)
        try:
            assert dispatcher.optimiser_ready is False
            warming = asyncio.ensure_future(dispatcher.warm_up())
            await asyncio.sleep(0.05)
            assert dispatcher.optimiser_ready is False  # compiling
            decider.release.set()
            await asyncio.wait_for(warming, 5.0)
            assert dispatcher.optimiser_ready is True
        finally:
            decider.release.set()
            stopping.set()
            dispatcher.close()


async def test_a_decider_without_warm_up_is_ready_at_once() -> None:
    class Plain:
        def decide(self, message: Message, now: float) -> Decision:
            return Decision(send=True, reason="test")

    dispatcher, stopping = _dispatcher(Plain())
    await dispatcher.warm_up()
    assert dispatcher.optimiser_ready is True
    stopping.set()
    dispatcher.close()


def test_the_station_shows_what_the_last_status_said() -> None:
    fv = FleetView(high_utility=3.0, link_lost_s=30.0)
    t0 = 1_700_000_000.0

    def status(seq: int, t: float, **data: object) -> None:
        fv.on_message(Message(sender="d1", seq=seq, type="status", t_gen=t, t_rcv=t + 0.1,
                              size=100, data=data), now=t + 0.1)

    status(1, t0, mode="GUIDED")  # an older companion: says nothing
    assert fv.drone_json(fv.drones["d1"], now=t0 + 1)["optimiser_ready"] is None
    status(2, t0 + 1, optimiser_ready=False)
    assert fv.drone_json(fv.drones["d1"], now=t0 + 2)["optimiser_ready"] is False
    status(3, t0 + 2, optimiser_ready=True)
    status(4, t0 + 1.5, optimiser_ready=False)  # reordered: older than what is shown
    status(5, t0 + 3, optimiser_ready="yes")  # not a bool: ignored
    assert fv.drone_json(fv.drones["d1"], now=t0 + 4)["optimiser_ready"] is True
