"""Operator checks (audit 12): a drone that restarted mid-mission is brought back into the
mission, and a restarted station keeps the mission it was running.

Before: a companion killed and restarted 40 s into a mission stayed ``idle`` (it waits for a
start, and the start had expired for it: ``command_ttl_s`` 30 s) while the station showed
``start: done 3/3``; a station restarted mid-mission showed phase ``idle`` with no command.
"""

from __future__ import annotations

import json
from pathlib import Path

from ground_station.mission_state import MissionStateFile, restore_missions, snapshot_missions
from ground_station.missions import MissionManager

T0 = 1_700_000_000.0


def _done(mm: MissionManager, drone: str, cid: int, t: float) -> None:
    mm.on_status(drone, state="ack", command_id=cid, now=t)
    mm.on_status(drone, state="done", command_id=cid, now=t)


def _running_mission() -> tuple[MissionManager, int, int]:
    """Two drones; a start and a set_params both done long ago (expired)."""
    mm = MissionManager(retry_s=0.5, command_ttl_s=30.0)
    for d in ("d1", "d2"):
        mm.on_drone_heard(d, now=T0)
    start = mm.issue("start", t_exec=T0 + 1, now=T0).command.command_id
    params = mm.issue("params", t_exec=T0 + 2, now=T0 + 2,
                      args={"mcts_iterations": 77}).command.command_id
    mm.due(now=T0 + 2)
    for d in ("d1", "d2"):
        _done(mm, d, start, T0 + 1.1)
        _done(mm, d, params, T0 + 2.1)
    assert mm.due(now=T0 + 100) == []
    return mm, start, params


def test_a_restarted_drone_gets_the_start_and_the_params_again() -> None:
    mm, start, params = _running_mission()
    assert mm.rejoin("d2", now=T0 + 100) == 2
    sent = mm.due(now=T0 + 100)
    assert [(d, c.command_id) for d, c in sent] == [("d2", start), ("d2", params)]
    by_id = {c["command_id"]: c for c in mm.state(now=T0 + 100)["commands"]}
    assert by_id[start]["results"]["d2"]["result"] == "sent"  # not the old life's "done"
    assert by_id[start]["results"]["d1"]["result"] == "done"
    _done(mm, "d2", start, T0 + 100.6)
    _done(mm, "d2", params, T0 + 100.6)
    assert mm.due(now=T0 + 101) == [] and mm.get_timer() is None
    # re-armed for d2 only, and only for command_ttl_s
    assert mm.rejoin("d2", now=T0 + 200) == 2
    assert [d for d, _ in mm.due(now=T0 + 200)] == ["d2", "d2"]
    assert mm.due(now=T0 + 231) == []


def test_an_idle_drone_in_a_running_mission_rejoins_once() -> None:
    mm, *_ = _running_mission()
    # a status generated before the start's result says nothing
    assert mm.on_mission_state("d2", "idle", t_gen=T0 + 1.0, now=T0 + 3) == 0
    assert mm.on_mission_state("d2", "running", t_gen=T0 + 50, now=T0 + 50) == 0
    assert mm.on_mission_state("d2", "idle", t_gen=T0 + 50, now=T0 + 50) == 2
    assert mm.on_mission_state("d2", "idle", t_gen=T0 + 51, now=T0 + 51) == 0  # on its way
    assert [d for d, _ in mm.due(now=T0 + 51)] == ["d2", "d2"]


def test_a_drone_heard_after_the_start_expired_joins_the_mission() -> None:
    mm, *_ = _running_mission()
    mm.on_drone_heard("late", now=T0 + 60)
    assert mm.due(now=T0 + 60) == []  # expired: the old rule sends nothing
    assert mm.on_mission_state("late", "idle", t_gen=T0 + 60, now=T0 + 60) == 2
    assert [d for d, _ in mm.due(now=T0 + 60)] == ["late", "late"]


def test_the_mission_phase_decides_who_rejoins() -> None:
    mm, *_ = _running_mission()
    end = mm.issue("end", t_exec=T0 + 10, now=T0 + 9).command.command_id
    mm.due(now=T0 + 9)
    _done(mm, "d1", end, T0 + 10)
    _done(mm, "d2", end, T0 + 10)
    # ended: an idle drone is fine, a running one (restarted without wait_for_start) is not
    assert mm.on_mission_state("d1", "idle", t_gen=T0 + 60, now=T0 + 60) == 0
    assert mm.on_mission_state("d2", "running", t_gen=T0 + 60, now=T0 + 60) == 3
    assert [c.name for _, c in mm.due(now=T0 + 60)] == ["start", "set_params", "end"]
    idle = MissionManager(retry_s=0.5)
    idle.on_drone_heard("d1", now=T0)
    assert idle.on_mission_state("d1", "idle", t_gen=T0, now=T0) == 0  # no mission yet


def test_the_commands_that_make_the_mission_are_kept_past_an_hour() -> None:
    mm, *_ = _running_mission()
    for k in range(3):
        mm.issue("report", t_exec=T0 + 10 + k, now=T0 + 10 + k)
    mm.issue("report", t_exec=T0 + 9000, now=T0 + 9000)  # forgets what is long past
    assert [c.command.name for c in mm.commands.values()] == ["start", "set_params",
                                                              "request_report"]
    assert mm.rejoin("d1", now=T0 + 9000) == 2


def test_the_mission_survives_a_station_restart(tmp_path: Path) -> None:
    mm, start, params = _running_mission()
    mm.on_status("d1", state="done", command_id=None, now=T0 + 5)  # a named report
    file = MissionStateFile(tmp_path / "mission_state.json")
    file.save(snapshot_missions(mm, "m"), mm.changes)
    file.save({"stale": True}, mm.changes - 1)  # an older snapshot never overwrites
    again = MissionManager(retry_s=0.5, command_ttl_s=30.0, first_command_id=5)
    assert restore_missions(again, file.load(), "other") == 0  # another mission's state
    assert again.phase(now=T0 + 100) == "idle" and again.commands == {}
    assert restore_missions(again, file.load(), "m") == 2
    assert again.phase(now=T0 + 100) == "running"
    assert again.params == {"mcts_iterations": 77}
    assert again.report_counts == {"done": 1}
    assert again.state(now=T0 + 100)["commands"] == mm.state(now=T0 + 100)["commands"]
    assert again.issue("report", t_exec=T0 + 101, now=T0 + 101).command.command_id > params
    # the restarted station still brings back a drone that restarts after it
    again.on_drone_heard("d2", now=T0 + 110)
    assert again.on_mission_state("d2", "idle", t_gen=T0 + 110, now=T0 + 110) == 2
    report = max(again.commands)  # live still: d2 gets it too
    assert [c.command_id for _, c in again.due(now=T0 + 110)] == [start, params, report]


def test_a_damaged_mission_state_file_starts_empty(tmp_path: Path) -> None:
    path = tmp_path / "mission_state.json"
    path.write_text('{"version": 1, "t_start": "x", "commands": [{"command_id": 1}]')
    assert MissionStateFile(path).load() == {}
    path.write_text(json.dumps({"version": 1, "mission": "m", "t_start": T0,
                                "commands": [{"name": "start"}]}))
    mm = MissionManager(retry_s=0.5)
    assert restore_missions(mm, MissionStateFile(path).load(), "m") == 0
    assert mm.t_start == T0 and mm.commands == {}


def test_a_drone_back_after_a_long_outage_gets_the_commands_it_missed() -> None:
    mm, *_ = _running_mission()
    missed = mm.issue("params", t_exec=T0 + 10, now=T0 + 10, args={"alpha": 5})
    cid = missed.command.command_id
    mm.due(now=T0 + 10)
    _done(mm, "d1", cid, T0 + 10.1)  # d2 is out of reach: sent, never acknowledged
    report = mm.issue("report", t_exec=T0 + 11, now=T0 + 11).command.command_id
    assert mm.due(now=T0 + 100) == [] and missed.result("d2", T0 + 100) == "no reply"
    assert mm.catch_up("d2", now=T0 + 100) == 1  # not the start, params it has, nor report
    assert [(d, c.command_id) for d, c in mm.due(now=T0 + 100)] == [("d2", cid)]
    assert report not in {c.command_id for _, c in mm.due(now=T0 + 200)}
    _done(mm, "d2", cid, T0 + 100.2)
    assert missed.result("d2", T0 + 101) == "done"  # a late answer counts
    assert mm.catch_up("d2", now=T0 + 200) == 0 and mm.catch_up("d1", now=T0 + 200) == 0


def test_superseded_params_are_not_sent_again_and_a_silent_drone_is_not_flooded() -> None:
    mm, start, first = _running_mission()  # first: mcts_iterations=77
    alpha = mm.issue("params", t_exec=T0 + 3, now=T0 + 3, args={"alpha": 5}).command.command_id
    again = mm.issue("params", t_exec=T0 + 4, now=T0 + 4,
                     args={"mcts_iterations": 9}).command.command_id  # supersedes first
    bad = mm.issue("params", t_exec=T0 + 5, now=T0 + 5, args={"alpha": 1, "warp": 2})
    mm.on_status("d1", state="error", command_id=bad.command.command_id, now=T0 + 5.1,
                 info={"error": "unknown parameter 'warp'"})  # rejected: alpha=5 holds
    assert [c.command.command_id for c in mm.state_commands()] == [
        start, alpha, again, bad.command.command_id]
    assert first not in [c.command.command_id for c in mm.state_commands()]
    # a drone that never answers (say, the wrong command key) is sent them again once
    mm.on_drone_heard("deaf", now=T0 + 60)
    assert mm.on_mission_state("deaf", "idle", t_gen=T0 + 60, now=T0 + 60) == 4
    assert mm.on_mission_state("deaf", "idle", t_gen=T0 + 200, now=T0 + 200) == 0
    assert mm.due(now=T0 + 200) == []


def test_a_drone_that_answers_the_resent_start_and_stays_ended_is_not_flooded() -> None:
    """A drone that did not restart answers a resent start from its memory: sending it the
    same command every 2 s changed nothing and logged a line each time (39 in 38 s). Now at
    most every 30 s; a restart (new epoch) still brings it back at once."""
    mm, start, params = _running_mission()
    assert mm.on_mission_state("d1", "ended", t_gen=T0 + 50, now=T0 + 50) == 2
    mm.due(now=T0 + 50)
    _done(mm, "d1", start, T0 + 50.1)  # the answer it remembers
    assert mm.on_mission_state("d1", "ended", t_gen=T0 + 52, now=T0 + 52) == 0
    assert mm.on_mission_state("d1", "ended", t_gen=T0 + 79, now=T0 + 79) == 0
    assert mm.on_mission_state("d1", "ended", t_gen=T0 + 81, now=T0 + 81) == 2
    mm.rejoin("d1", now=T0 + 95)
    assert [c.command_id for d, c in mm.due(now=T0 + 95) if d == "d1"] == [start, params]
