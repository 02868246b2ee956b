"""The operator's latest start or end decides from its time on (found trying the product).

* ``start +5`` then ``end`` (now): the drones ran the end first and the start at +5, so the
  fleet streamed after "end mission"; the station said ``running`` with t_end < t_start and
  ``uav-utility evaluate`` refused the mission log.
* ``end +30``, ``end``, ``start``: at +30 the first end still ran on every drone; the
  station said ``running`` for the rest of the flight and resent the start every 2 s to no
  effect.

A start or end replaces those issued before it that have not run and would run at or
after it; earlier ones (``start +5`` then ``end +30``: a window) are kept.
"""

from __future__ import annotations

import asyncio
import time
from pathlib import Path
from typing import Any

from companion.commands import CommandExecutor
from companion.config import parse_config
from companion.dispatch import COUNTERS, Dispatcher
from companion.middleware.decider import Decision
from companion.mission import MissionWindow
from companion.mission_log import MissionLogWriter
from companion.protocol import Command, Status
from ground_station.fake_drone import FakeDrone
from ground_station.mission_state import restore_missions, snapshot_missions
from ground_station.missions import MissionManager
from ground_station.storage import Storage
from utility_specs.files import read_log
from utility_specs.intervals import MissionInterval, intervals_of
from utility_specs.message import Message

T0 = 1_700_000_000.0


def manager() -> MissionManager:
    mm = MissionManager(retry_s=0.5)
    mm.on_drone_heard("d1", now=T0)
    return mm


def sent(mm: MissionManager, now: float) -> list[str]:
    return [c.name for _, c in mm.due(now=now)]


def test_an_end_while_a_start_is_scheduled_cancels_the_start() -> None:
    mm = manager()
    start = mm.issue("start", t_exec=T0 + 5, now=T0)
    assert sent(mm, T0) == ["start"]
    end = mm.issue("end", t_exec=T0 + 1, now=T0 + 1)
    assert start.superseded_by == end.command.command_id
    assert (mm.t_start, mm.t_end) == (None, None)
    assert mm.phase(now=T0 + 10) == "idle"  # the mission never started
    assert sent(mm, T0 + 3) == ["end"]  # the start is not sent again
    assert [c.command.name for c in mm.state_commands()] == []
    outcome = start.outcome(T0 + 20)
    assert outcome["results"]["d1"]["result"] == "superseded"
    assert outcome["finished"] and outcome["summary"]["superseded"] == 1
    assert mm.get_timer() is None or all(c.name != "start" for _, c in mm.due(now=T0 + 9))


def test_a_start_after_a_scheduled_end_is_not_ended_by_it() -> None:
    mm = manager()
    mm.issue("start", t_exec=T0, now=T0)
    later_end = mm.issue("end", t_exec=T0 + 30, now=T0 + 1)
    end_now = mm.issue("end", t_exec=T0 + 2, now=T0 + 2)
    assert later_end.superseded_by == end_now.command.command_id
    assert mm.phase(now=T0 + 3) == "ended" and mm.t_end == T0 + 2
    mm.issue("start", t_exec=T0 + 4, now=T0 + 4)
    assert mm.phase(now=T0 + 40) == "running" and mm.t_end is None
    assert later_end.command not in [c for _, c in mm.due(now=T0 + 31)]
    assert [c.command.name for c in mm.state_commands()] == ["start"]


def test_a_start_then_a_later_end_is_a_window_and_both_run() -> None:
    mm = manager()
    start = mm.issue("start", t_exec=T0 + 5, now=T0)
    end = mm.issue("end", t_exec=T0 + 30, now=T0 + 1)
    assert start.superseded_by is None and end.superseded_by is None
    assert [mm.phase(now=T0 + t) for t in (1, 6, 31)] == ["scheduled", "running", "ended"]
    assert sorted(sent(mm, T0 + 1)) == ["end", "start"]


def test_a_replaced_command_stays_replaced_after_a_station_restart() -> None:
    mm = manager()
    start = mm.issue("start", t_exec=T0 + 5, now=T0)
    mm.issue("end", t_exec=T0 + 1, now=T0 + 1)
    again = MissionManager(retry_s=0.5)
    restore_missions(again, snapshot_missions(mm, "m"), "m")
    assert again.commands[start.command.command_id].superseded_by is not None
    assert again.phase(now=T0 + 10) == "idle"
    again.on_drone_heard("d1", now=T0 + 2)
    assert "start" not in [c.name for _, c in again.due(now=T0 + 2)]


def test_the_storage_forgets_a_cancelled_start(tmp_path: Path) -> None:
    s = Storage(tmp_path, fsync=False)
    s.mark_mission("m", now=T0, t_start=T0, opened=True)  # the station's own, first message
    s.mark_mission("m", now=T0 + 1, t_start=T0 + 5)  # the operator's, scheduled
    s.cancel_starts("m", [T0 + 5], now=T0 + 2)
    row = s.db.execute("SELECT t_start, t_end FROM missions WHERE name = 'm'").fetchone()
    assert tuple(row) == (T0, None)
    kinds = [r[0] for r in s.db.execute("SELECT kind FROM mission_bounds ORDER BY rowid")]
    assert kinds == ["open"]
    s.mark_mission("m", now=T0 + 60, t_end=T0 + 60, stop=True)
    s.close()
    log = read_log(s.log_path("m"))  # the evaluated interval: as if never scheduled
    assert intervals_of(log.bounds, "gs", log.bound_kinds) == [
        MissionInterval(T0, T0 + 60, "gs")]


def test_a_cancelled_start_with_nothing_before_it_opens_no_run(tmp_path: Path) -> None:
    s = Storage(tmp_path, fsync=False)
    s.mark_mission("m", now=T0, t_start=T0 + 5)
    s.cancel_starts("m", [T0 + 5], now=T0 + 1)
    s.mark_mission("m", now=T0 + 9, t_start=T0 + 9)  # the operator's next start
    s.mark_mission("m", now=T0 + 20, t_end=T0 + 20)
    s.close()
    log = read_log(s.log_path("m"))
    assert intervals_of(log.bounds, "gs", log.bound_kinds) == [
        MissionInterval(T0 + 9, T0 + 20, "gs")]


class _Decider:
    def decide(self, message: Message, now: float) -> Decision:
        return Decision(send=True, reason="test")

    def get_timer(self) -> float | None:
        return None


async def _drone(tmp_path: Path, commands: list[tuple[int, str, float]], wait_s: float
                 ) -> tuple[MissionWindow, dict[int, Status]]:
    """A companion's command executor given ``commands`` (id, name, delay) in that order."""
    mission = MissionWindow("idle")
    log = MissionLogWriter(tmp_path / "mission_log.jsonl")
    dispatcher = Dispatcher(parse_config({"drone": {"id": "d1"}}), decider=_Decider(),  # type: ignore[arg-type]
                            clock=time.time, send_message=lambda m, p, t: 1, mission_log=log,
                            mission=mission, counters=dict.fromkeys(COUNTERS, 0))
    results: dict[int, Status] = {}

    def status(s: Status, now: float) -> int:
        if s.state in ("done", "error"):
            results[s.command_id or 0] = s
        return 1

    executor = CommandExecutor(drone_id="d1", clock=time.time, send_status=status,
                               dispatcher=dispatcher, mission=mission, mission_log=log,
                               on_done=lambda now: None)
    t0 = time.time()
    try:
        for cid, name, delay in commands:
            executor.schedule(Command(command_id=cid, name=name, t_exec=t0 + delay))
        await asyncio.sleep(wait_s)
    finally:
        executor.close()
        dispatcher.close()
        log.close()
    return mission, results


async def test_a_drone_skips_a_start_an_end_issued_after_it_replaced(tmp_path: Path) -> None:
    mission, results = await _drone(tmp_path, [(7, "start", 0.3), (8, "end", 0.0)], 0.6)
    assert mission.state == "ended"  # not running: the start at +0.3 was skipped
    assert results[8].state == "done"
    assert results[7].state == "error" and "superseded by end #8" in _error(results[7])


async def test_a_drone_skips_a_scheduled_end_a_later_start_replaced(tmp_path: Path) -> None:
    mission, results = await _drone(
        tmp_path, [(1, "start", 0.0), (2, "end", 0.4), (3, "end", 0.05), (4, "start", 0.1)],
        0.7)
    assert mission.state == "running"
    assert [results[i].state for i in (1, 2, 3, 4)] == ["done", "error", "done", "done"]


async def test_a_drone_runs_a_window_and_ids_that_wrapped(tmp_path: Path) -> None:
    mission, results = await _drone(tmp_path, [(2**32 - 1, "start", 0.05), (1, "end", 0.2)],
                                    0.5)
    assert mission.state == "ended"
    assert results[2**32 - 1].state == "done" and results[1].state == "done"
    mission, results = await _drone(tmp_path, [(2**32 - 1, "start", 0.3), (1, "end", 0.0)],
                                    0.5)
    assert mission.state == "ended" and results[2**32 - 1].state == "error"


def _error(status: Status) -> str:
    info: dict[str, Any] = dict(status.info or {})
    return str(info.get("error"))


def test_the_fake_drone_skips_a_replaced_start_as_the_companion_does() -> None:
    drone = FakeDrone("d1", fleet_id=1, key=b"k" * 32, ground=("127.0.0.1", 9))
    start = Command(command_id=7, name="start", t_exec=T0 + 5)
    end = Command(command_id=8, name="end", t_exec=T0)
    for command in (start, end):
        drone._phase[command.command_id] = (command.name, command.t_exec)
    assert drone._refusal(end) is None
    assert drone._refusal(start) == "superseded by end #8"
