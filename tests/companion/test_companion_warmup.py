"""While the optimiser warms up (numba compiles on a cold cache: 10.7 s measured for four
drones on two cores), the status heartbeat still goes out, so the station never flags the
drone lost; everything else waits for the optimiser (found in `make demo` on a fresh clone)."""

from __future__ import annotations

import asyncio
import threading
import time

from companion.config import parse_config
from companion.dispatch import COUNTERS, Dispatcher
from companion.middleware.decider import Decision
from companion.mission import MissionWindow
from companion.mission_log import MissionLogWriter
from utility_specs.message import Message


class SlowToWarm:
    """A decider whose warm-up holds its thread until released; it drops everything."""

    def __init__(self) -> None:
        self.release = threading.Event()
        self.decided: list[Message] = []

    def warm_up(self) -> None:
        self.release.wait(10.0)

    def decide(self, message: Message, now: float) -> Decision:
        self.decided.append(message)
        return Decision(send=False, reason="test")

    def get_timer(self) -> float | None:
        return None


def _message(seq: int, type_name: str) -> Message:
    return Message(sender="d1", seq=seq, type=type_name, t_gen=time.time(), size=100,
                   data={})


async def test_statuses_go_out_while_the_optimiser_warms_up() -> None:
    config = parse_config({"drone": {"id": "d1"}})
    counters = dict.fromkeys(COUNTERS, 0)
    decider, sent = SlowToWarm(), []
    dispatcher = Dispatcher(config, decider=decider, clock=time.time,  # type: ignore[arg-type]
                            send_message=lambda m, p, t: sent.append(m) or 1,
                            mission_log=MissionLogWriter(None), mission=MissionWindow("running"),
                            counters=counters)
    stopping = asyncio.Event()
    dispatcher.bind(stopping)
    warming = asyncio.ensure_future(dispatcher.warm_up())
    try:
        await asyncio.sleep(0.05)
        assert await dispatcher.submit(_message(0, "status"))  # sent without the optimiser
        assert not await dispatcher.submit(_message(1, "position"))  # waits for it: dropped
        assert [m.seq for m in sent] == [0] and decider.decided == []
        assert counters["warming_up"] == 1 and counters["decide_timeouts"] == 0
        decider.release.set()
        await asyncio.wait_for(warming, 5.0)
        assert not await dispatcher.submit(_message(2, "status"))  # the policy decides again
        assert [m.seq for m in decider.decided] == [2]
    finally:
        decider.release.set()
        stopping.set()
        dispatcher.close()


class FailsToWarm(SlowToWarm):
    def warm_up(self) -> None:
        raise RuntimeError("no compiler")


async def _warm(decider: SlowToWarm, after: list[str]) -> Dispatcher:
    config = parse_config({"drone": {"id": "d1"}})
    dispatcher = Dispatcher(config, decider=decider, clock=time.time,  # type: ignore[arg-type]
                            send_message=lambda m, p, t: 1, mission_log=MissionLogWriter(None),
                            mission=MissionWindow("running"),
                            counters=dict.fromkeys(COUNTERS, 0))
    dispatcher.after_warm_up = lambda: after.append(threading.current_thread().name)
    stopping = asyncio.Event()
    dispatcher.bind(stopping)
    decider.release.set()
    try:
        await asyncio.wait_for(dispatcher.warm_up(), 5.0)
    finally:
        stopping.set()
        dispatcher.close()
    return dispatcher


async def test_the_after_warm_up_hook_runs_once_in_the_deciders_thread() -> None:
    after: list[str] = []
    dispatcher = await _warm(SlowToWarm(), after)
    assert dispatcher.optimiser_ready
    assert len(after) == 1 and after[0] != threading.main_thread().name


async def test_a_failed_warm_up_skips_the_hook() -> None:
    after: list[str] = []
    dispatcher = await _warm(FailsToWarm(), after)
    assert dispatcher.optimiser_ready and after == []


def test_the_console_script_freezes_the_startup_heap_out_of_the_collectors_reach() -> None:
    import gc

    from companion.cli import freeze_startup_heap

    before = gc.get_freeze_count()
    try:
        freeze_startup_heap()
        assert gc.get_freeze_count() > before
    finally:
        gc.unfreeze()  # the test process collects as before
