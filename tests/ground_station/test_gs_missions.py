"""Mission manager core: time arguments, parameters, terminal lines, resends until acked."""

from __future__ import annotations

import datetime as dt

import pytest
from hypothesis import given
from hypothesis import strategies as st

from ground_station.missions import (
    MissionError,
    MissionManager,
    parse_params,
    parse_shell_line,
    parse_when,
)

T0 = 1_700_000_000.0  # 2023-11-14 22:13:20 UTC
UTC = dt.UTC


@pytest.mark.parametrize(
    ("text", "offset"),
    [
        (None, 0.0),
        ("now", 0.0),
        ("+5", 5.0),
        ("in 5 s", 5.0),
        ("5s", 5.0),
        ("in 2.5 seconds", 2.5),
        ("in 2 min", 120.0),
        ("+1m", 60.0),
    ],
)
def test_relative_times(text: str | None, offset: float) -> None:
    assert parse_when(text, now=T0) == T0 + offset


def test_at_clock_time_today_and_tomorrow() -> None:
    # 22:13:20 UTC now: 23:00 is later today, 14:00 is tomorrow.
    assert parse_when("at 23:00", now=T0, tz=UTC) == T0 + (46 * 60 + 40)
    assert parse_when("at 14:00", now=T0, tz=UTC) == T0 + (24 * 3600 - (8 * 3600 + 13 * 60 + 20))
    assert parse_when("22:13:30.5", now=T0, tz=UTC) == T0 + 10.5


@pytest.mark.parametrize("text", ["soon", "at 25:00", "in -5 s", "at 12:61", "5 h"])
def test_bad_times_are_clear_errors(text: str) -> None:
    with pytest.raises(MissionError, match="time"):
        parse_when(text, now=T0)


@given(st.floats(min_value=0, max_value=1e5, allow_nan=False).map(lambda x: round(x, 3)))
def test_in_seconds_property(seconds: float) -> None:
    assert parse_when(f"in {seconds} s", now=T0) == pytest.approx(T0 + seconds, abs=1e-6)


def test_parse_params_types() -> None:
    assert parse_params("alpha=10, mcts_iterations=300, goodput_alpha=0.5, adaptive=true") == {
        "alpha": 10,
        "mcts_iterations": 300,
        "goodput_alpha": 0.5,
        "adaptive": True,
    }
    assert parse_params("scorer=red_share") == {"scorer": "red_share"}
    for bad in ("alpha", "=3", "", "a b=1", "x=nan"):
        with pytest.raises(MissionError):
            parse_params(bad)
    with pytest.raises(MissionError, match="separate parameters with commas"):
        parse_params("alpha=12 mcts_iterations=300")


def test_shell_lines_of_figure_3_7() -> None:
    assert parse_shell_line("s +5").verb == "start"  # type: ignore[union-attr]
    assert parse_shell_line("s +5").when == "+5"  # type: ignore[union-attr]
    assert parse_shell_line("e").when is None  # type: ignore[union-attr]
    p = parse_shell_line("p J=1,K=1,M=4")
    assert p is not None and p.verb == "params" and dict(p.params) == {"J": 1, "K": 1, "M": 4}
    assert parse_shell_line("p alpha=3 @ in 2 s").when == "in 2 s"  # type: ignore[union-attr]
    n = parse_shell_line("n 4")
    assert n is not None and (n.verb, n.count) == ("wait_drones", 4)
    r = parse_shell_line("r 3 done")
    assert r is not None and (r.verb, r.count, r.report) == ("wait_reports", 3, "done")
    r = parse_shell_line("r")
    assert r is not None and (r.count, r.report) == (None, None)
    assert parse_shell_line("rr").verb == "reset_reports"  # type: ignore[union-attr]
    assert parse_shell_line("l 0.5").seconds == 0.5  # type: ignore[union-attr]
    assert [parse_shell_line(x).verb for x in "hcq"] == ["help", "close", "quit"]  # type: ignore[union-attr]
    assert parse_shell_line("   ") is None
    for bad in ("x", "n four", "l soon", "r 1 a b"):
        with pytest.raises(MissionError):
            parse_shell_line(bad)


def test_command_resent_until_acked_with_exact_deadlines() -> None:
    mm = MissionManager(retry_s=0.5, command_ttl_s=10.0)
    mm.on_drone_heard("d1", now=T0)
    mm.on_drone_heard("d2", now=T0)
    issued = mm.issue("start", t_exec=T0 + 5, now=T0)
    cid = issued.command.command_id
    assert issued.command.name == "start" and issued.command.t_exec == T0 + 5
    assert mm.get_timer() == T0
    assert [(d, c.command_id) for d, c in mm.due(now=T0)] == [("d1", cid), ("d2", cid)]
    assert mm.get_timer() == T0 + 0.5
    assert mm.due(now=T0 + 0.4) == []
    mm.on_status("d1", state="ack", command_id=cid, now=T0 + 0.45)
    assert [d for d, _ in mm.due(now=T0 + 0.5)] == ["d2"]
    assert mm.get_timer() == T0 + 1.0
    mm.on_status("d2", state="ack", command_id=cid, now=T0 + 0.6)
    # acknowledged by all: nothing more until the result is due (t_exec + one retry)
    assert mm.get_timer() == T0 + 5.5
    assert mm.due(now=T0 + 5.4) == []
    mm.on_status("d1", state="done", command_id=cid, now=T0 + 5.1)
    assert [d for d, _ in mm.due(now=T0 + 5.5)] == ["d2"]  # its "done" may have been lost
    mm.on_status("d2", state="done", command_id=cid, now=T0 + 5.6)
    assert mm.get_timer() is None
    assert mm.phase(now=T0 + 1) == "scheduled"
    assert mm.phase(now=T0 + 5) == "running"


def test_late_drone_gets_live_command_but_not_expired_one() -> None:
    mm = MissionManager(retry_s=1.0, command_ttl_s=10.0)
    old = mm.issue("params", t_exec=T0, now=T0, args={"alpha": 3})
    live = mm.issue("start", t_exec=T0 + 30, now=T0)
    mm.on_drone_heard("late", now=T0 + 20)
    due = mm.due(now=T0 + 20)
    assert [c.command_id for _, c in due] == [live.command.command_id]
    assert old.command.command_id != live.command.command_id
    assert mm.params == {"alpha": 3}


def test_reports_count_state_changes() -> None:
    mm = MissionManager(retry_s=1.0)
    for t in range(3):
        mm.on_status("d1", state="running", command_id=None, now=T0 + t)
    mm.on_status("d1", state="done", command_id=None, now=T0 + 4)
    mm.on_status("d2", state="done", command_id=None, now=T0 + 4)
    assert mm.report_counts == {"running": 1, "done": 2}
    assert mm.report_drones["done"] == {"d1", "d2"}
    # an ack of an unknown command (e.g. before a restart) is not a report
    mm.on_status("d1", state="ack", command_id=12345, now=T0 + 5)
    assert "ack" not in mm.report_counts
    mm.reset_reports()
    assert mm.state(now=T0)["reports"] == {}


def test_issue_rejects_bad_input() -> None:
    mm = MissionManager(retry_s=1.0)
    with pytest.raises(MissionError):
        mm.issue("launch", t_exec=T0, now=T0)
    with pytest.raises(MissionError):
        mm.issue("params", t_exec=T0, now=T0, args={})
    with pytest.raises(MissionError):
        mm.issue("start", t_exec=float("nan"), now=T0)
