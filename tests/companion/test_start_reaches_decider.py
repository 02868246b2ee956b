"""The station's ``start`` reaches the optimiser (``Middleware.mission_started``), in its
executor, before any data the started mission sends: the fleet's start share counts from it."""

from __future__ import annotations

import asyncio
import threading
import time
from pathlib import Path

from companion.commands import CommandExecutor
from companion.config import parse_config
from companion.dispatch import COUNTERS, Dispatcher
from companion.middleware.decider import Decision
from companion.mission import MissionWindow
from companion.mission_log import MissionLogWriter
from companion.protocol import Command
from utility_specs.message import Message


class StartAware:
    def __init__(self) -> None:
        self.calls: list[tuple[str, float, str]] = []

    def decide(self, message: Message, now: float) -> Decision:
        self.calls.append(("decide", now, threading.current_thread().name))
        return Decision(send=True, reason="test")

    def mission_started(self, now: float) -> None:
        self.calls.append(("mission_started", now, threading.current_thread().name))

    def get_timer(self) -> float | None:
        return None


async def test_the_start_command_tells_the_decider_before_the_missions_data(
        tmp_path: Path) -> None:
    decider = StartAware()
    mission = MissionWindow("idle")  # wait_for_start, as uav-sitl fleet's companions
    mission_log = MissionLogWriter(tmp_path / "mission_log.jsonl")
    dispatcher = Dispatcher(parse_config({"drone": {"id": "d1"}}), decider=decider,  # type: ignore[arg-type]
                            clock=time.time, send_message=lambda m, p, t: 1,
                            mission_log=mission_log, mission=mission,
                            counters=dict.fromkeys(COUNTERS, 0))
    stopping = asyncio.Event()
    dispatcher.bind(stopping)
    executor = CommandExecutor(drone_id="d1", clock=time.time,
                               send_status=lambda status, now: 1, dispatcher=dispatcher,
                               mission=mission, mission_log=mission_log,
                               on_done=lambda now: None)
    try:
        t_exec = time.time() + 0.05
        executor.schedule(Command(command_id=7, name="start", t_exec=t_exec))
        async with asyncio.timeout(5):
            while not mission.running:
                await asyncio.sleep(0.01)
        await dispatcher.submit(Message(sender="d1", seq=1, type="image", t_gen=time.time(),
                                        size=8_000))
    finally:
        stopping.set()
        dispatcher.close()
        executor.close()
        mission_log.close()
    names = [name for name, _, _ in decider.calls]
    assert names == ["mission_started", "decide"]
    started_at, thread = decider.calls[0][1], decider.calls[0][2]
    assert t_exec <= started_at < t_exec + 1.0
    assert thread == decider.calls[1][2] != threading.main_thread().name  # its executor


async def test_a_decider_without_the_hook_is_left_alone(tmp_path: Path) -> None:
    class Plain:
        def decide(self, message: Message, now: float) -> Decision:
            return Decision(send=True, reason="test")

        def get_timer(self) -> float | None:
            return None

    dispatcher = Dispatcher(parse_config({"drone": {"id": "d1"}}), decider=Plain(),  # type: ignore[arg-type]
                            clock=time.time, send_message=lambda m, p, t: 1,
                            mission_log=MissionLogWriter(tmp_path / "log.jsonl"),
                            mission=MissionWindow("running"),
                            counters=dict.fromkeys(COUNTERS, 0))
    dispatcher.mission_started()  # no hook: nothing to tell, nothing raised
