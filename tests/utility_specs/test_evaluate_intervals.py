"""``uav-utility evaluate`` says which mission interval it evaluated and why (issue 11, 5)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from utility_specs.intervals import MissionInterval, intervals_of, select_intervals


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "utility_specs.cli", *args],
                          capture_output=True, text=True, timeout=120, check=False)


def _battery(seq: int, t: float, *, received: bool) -> dict[str, object]:
    return {"sender": "d1", "receiver": "gs" if received else None, "seq": seq,
            "type": "battery", "t_gen": t, "t_sent": t, "t_rcv": t if received else None,
            "size": 10, "data": {"level": 1.0}}


def _write(path: Path, records: list[dict[str, object]]) -> Path:
    path.write_text("".join(json.dumps(r) + "\n" for r in records))
    return path


@pytest.fixture
def logs(tmp_path: Path) -> tuple[Path, Path]:
    """A ground station log with a mission created at 0, started at 10, ended at 20, then a
    second mission 30..34; a drone log whose process ran 0..40 (like a real demo's)."""
    gs = _write(tmp_path / "gs.jsonl", [
        {"mission": {"t_start": 0.0}}, {"mission": {"t_start": 10.0}},
        _battery(0, 10.0, received=True), {"mission": {"t_end": 20.0}},
        {"mission": {"t_start": 30.0}}, _battery(1, 30.0, received=True),
        {"mission": {"t_end": 34.0}},
    ])
    drone = _write(tmp_path / "drone.jsonl", [
        {"mission": {"t_start": 0.0}}, _battery(0, 10.0, received=False),
        _battery(1, 30.0, received=False), {"mission": {"t_end": 40.0}},
    ])
    return gs, drone


# battery (telemetry spec): level 1.0 decays 0.01/s, so ∫ over d seconds = d - 0.005 d²
FIRST = 10.0 - 0.005 * 100   # [10, 20]
SECOND = 4.0 - 0.005 * 16    # [30, 34]


def test_intervals_follow_start_and_end_records() -> None:
    bounds = [(0.0, None), (10.0, None), (None, 20.0), (None, 25.0), (30.0, None)]
    assert intervals_of(bounds, "gs") == [
        MissionInterval(10.0, 20.0, "gs"), MissionInterval(None, 25.0, "gs"),
        MissionInterval(30.0, None, "gs")]


def test_a_station_restart_is_one_interval_not_two_overlapping() -> None:
    """The station's stop ends the run, its restart writes the same start again: [10, 20]
    is the first part of [10, 35] (it was listed as a second, overlapping interval)."""
    gs = intervals_of([(10.0, None), (None, 20.0), (10.0, None), (None, 35.0)], "gs")
    chosen = select_intervals([gs], [], None)
    assert chosen.candidates == chosen.chosen == [MissionInterval(10.0, 35.0, "gs")]
    assert "the only mission interval" in chosen.why


def test_an_operators_second_start_goes_on_with_the_open_run() -> None:
    """As the station's report does: the launcher (or an operator) starts at 10, the
    operator presses start at 23: the mission is [10, 60], not [23, 60] (the station's own
    ``open`` at its first message is replaced by a start, and a cancelled start opens
    nothing)."""
    bounds = [(5.0, None), (10.0, None), (23.0, None), (None, 60.0)]
    kinds = ["open", "start", "start", "end"]
    assert intervals_of(bounds, "gs", kinds) == [MissionInterval(10.0, 60.0, "gs")]
    assert intervals_of(bounds, "gs") == [MissionInterval(23.0, 60.0, "gs")]  # no kinds
    cancelled = [(5.0, None), (30.0, None), (30.0, None), (5.0, None), (None, 60.0)]
    kinds = ["open", "start", "cancelled", "open", "stop"]
    assert intervals_of(cancelled, "gs", kinds) == [MissionInterval(5.0, 60.0, "gs")]


def test_receiver_intervals_win_over_senders_process_lifetimes() -> None:
    gs = [MissionInterval(10.0, 20.0, "gs")]
    drone = [MissionInterval(0.0, 40.0, "drone")]
    chosen = select_intervals([gs], [drone], None)
    assert chosen.chosen == gs and "the only mission interval" in chosen.why
    assert select_intervals([], [drone], None).chosen == drone
    with pytest.raises(ValueError, match=r"numbered 1\.\.1"):
        select_intervals([gs], [drone], "2")


def test_several_intervals_default_to_the_last_and_say_so(logs: tuple[Path, Path]) -> None:
    gs, drone = logs
    result = _run("evaluate", "--spec", "telemetry", str(drone), str(gs))
    assert result.returncode == 0, result.stderr
    out = result.stdout
    assert f"mission interval 1: [10.000, 20.000] (10.0 s) from {gs}" in out
    assert f"mission interval 2: [30.000, 34.000] (4.0 s) from {gs}" in out
    assert ("interval: 2 mission intervals in the receiver's (ground station's) log; "
            "evaluating the last complete one, number 2 (choose with --mission N|last|all)"
            ) in out
    assert f"total utility  {SECOND:14.6f}" in out


def test_mission_chooses_by_number_last_or_all(logs: tuple[Path, Path]) -> None:
    gs, drone = logs
    first = _run("evaluate", "--spec", "telemetry", "--json", "--mission", "1", str(gs),
                 str(drone))
    assert first.returncode == 0, first.stderr
    one = json.loads(first.stdout)
    assert one["total"] == pytest.approx(FIRST)
    assert (one["t_start"], one["t_end"]) == (10.0, 20.0)
    assert one["interval"] == "mission interval 1 of 2 (--mission 1)"
    last = json.loads(_run("evaluate", "--spec", "telemetry", "--json", "--mission", "last",
                           str(gs)).stdout)
    assert last["total"] == pytest.approx(SECOND)
    every = json.loads(_run("evaluate", "--spec", "telemetry", "--json", "--mission", "all",
                            str(gs), str(drone)).stdout)
    assert [m["total"] for m in every["missions"]] == [pytest.approx(FIRST),
                                                       pytest.approx(SECOND)]


def test_log_order_does_not_change_the_interval(logs: tuple[Path, Path]) -> None:
    """The old code took the last mission record of the last file: the drone's 0..40."""
    gs, drone = logs
    a = json.loads(_run("evaluate", "--spec", "telemetry", "--json", str(gs), str(drone)).stdout)
    b = json.loads(_run("evaluate", "--spec", "telemetry", "--json", str(drone), str(gs)).stdout)
    assert a["total"] == b["total"] == pytest.approx(SECOND)


def test_bad_mission_choice_is_a_one_line_error(logs: tuple[Path, Path]) -> None:
    gs, _ = logs
    result = _run("evaluate", "--spec", "telemetry", "--mission", "3", str(gs))
    assert result.returncode == 2
    assert result.stderr.strip() == ("uav-utility: error: --mission 3: the logs hold 2 "
                                     "mission interval(s), numbered 1..2")
    bad = _run("evaluate", "--spec", "telemetry", "--mission", "first", str(gs))
    assert bad.returncode == 2 and "expected a number >= 1, last or all" in bad.stderr


def test_senders_logs_alone_warn_that_nothing_was_received(logs: tuple[Path, Path]) -> None:
    _, drone = logs
    result = _run("evaluate", "--spec", "telemetry", str(drone))
    assert result.returncode == 0
    assert "total utility        0.000000" in result.stdout
    assert ("warning: no record in these logs was received (no t_rcv): they hold only "
            "senders' records") in result.stderr
