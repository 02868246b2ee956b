"""Per-drone command results in the mission manager core: done, error, no reply."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from ground_station.missions import MissionManager, parse_shell_line

T0 = 1_700_000_000.0


def _fleet(*drones: str, reply_timeout_s: float = 5.0) -> MissionManager:
    mm = MissionManager(retry_s=0.5, reply_timeout_s=reply_timeout_s)
    for drone in drones:
        mm.on_drone_heard(drone, now=T0)
    return mm


def test_results_done_error_and_no_reply_with_exact_deadlines() -> None:
    mm = _fleet("a", "b", "c", "d")
    issued = mm.issue("params", t_exec=T0 + 10, now=T0, args={"x": 1})
    cid = issued.command.command_id
    mm.due(now=T0)
    for drone in "abc":
        mm.on_status(drone, state="ack", command_id=cid, now=T0 + 0.1)
    mm.on_status("a", state="done", command_id=cid, now=T0 + 10.1)
    mm.on_status("b", state="error", command_id=cid, now=T0 + 10.1,
                 info={"name": "set_params", "error": "unknown parameter 'x'"})
    before = issued.as_json(T0 + 14.9)
    assert {d: e["result"] for d, e in before["results"].items()} == {
        "a": "done", "b": "error", "c": "acked", "d": "sent"}
    assert before["summary"] == {"done": 1, "error": 1, "no reply": 0, "waiting": 2, "total": 4}
    assert before["finished"] is False
    after = issued.as_json(T0 + 15.0)  # t_exec + reply_timeout_s
    assert after["results"]["b"]["reason"] == "unknown parameter 'x'"
    assert after["results"]["c"] == {
        "result": "no reply", "reason": "no result 5 s after execution"}
    assert after["results"]["d"]["reason"] == (
        "no result 5 s after execution; never acknowledged")
    assert after["summary"] == {"done": 1, "error": 1, "no reply": 2, "waiting": 0, "total": 4}
    assert after["finished"] is True


def test_a_late_drone_gets_its_own_reply_deadline() -> None:
    mm = _fleet("a")
    issued = mm.issue("start", t_exec=T0, now=T0)
    mm.due(now=T0)
    mm.on_drone_heard("late", now=T0 + 20)
    assert "late" in [d for d, _ in mm.due(now=T0 + 20)]
    assert issued.result("late", T0 + 24.9) == "sent"
    assert issued.result("late", T0 + 25.0) == "no reply"
    assert issued.result("a", T0 + 24.9) == "no reply"


def test_the_report_command_carries_the_counters() -> None:
    mm = _fleet("a")
    issued = mm.issue("report", t_exec=T0, now=T0)
    assert issued.command.name == "request_report"
    mm.on_status("a", state="done", command_id=issued.command.command_id, now=T0 + 0.1,
                 info={"name": "request_report", "counters": {"sent": 7}})
    assert issued.as_json(T0 + 0.1)["results"]["a"]["info"]["counters"] == {"sent": 7}


STATES = st.sampled_from(["ack", "done", "error", "running"])


@given(st.lists(st.tuples(st.sampled_from("abc"), STATES), max_size=20),
       st.floats(min_value=0.0, max_value=20.0))
def test_a_final_result_is_never_undone_and_counts_add_up(
        statuses: list[tuple[str, str]], dt: float) -> None:
    mm = _fleet("a", "b", "c")
    issued = mm.issue("end", t_exec=T0 + 1, now=T0)
    cid = issued.command.command_id
    mm.due(now=T0)
    first_final: dict[str, str] = {}
    last_final: dict[str, str] = {}
    for i, (drone, state) in enumerate(statuses):
        mm.on_status(drone, state=state, command_id=cid, now=T0 + 0.01 * i)
        if state in ("done", "error"):
            first_final.setdefault(drone, state)
            last_final[drone] = state
    out = issued.as_json(T0 + dt)
    for drone, state in last_final.items():  # the latest final answer is what shows
        assert out["results"][drone]["result"] == state
        assert out["states"][drone] == state
    summary = out["summary"]
    assert summary["total"] == 3
    assert sum(summary[k] for k in ("done", "error", "no reply", "waiting")) == 3
    assert out["finished"] == (summary["waiting"] == 0)
    # a drone with a result is never sent the command again
    assert not {d for d, _ in mm.due(now=T0 + dt + 10)} & set(last_final)


def test_names_a_newcomer_guesses_and_the_old_letters() -> None:
    pairs = [("start +5", "s +5"), ("end", "e"), ("params a=1", "p a=1"), ("wait", "r"),
             ("drones 2", "n 2"), ("reset", "rr"), ("sleep 1", "l 1"), ("help", "h"),
             ("quit", "q"), ("close", "c")]
    for name, letter in pairs:
        assert parse_shell_line(name) == parse_shell_line(letter), name
    assert parse_shell_line("report").verb == "report"  # type: ignore[union-attr]
    assert parse_shell_line("status").verb == "status"  # type: ignore[union-attr]
    assert parse_shell_line("?").verb == "help"  # type: ignore[union-attr]


def test_a_parameter_every_drone_rejected_is_not_shown_in_effect() -> None:
    """Before: ``params`` was every key ever asked, so ``warp_speed=2`` after ``error 2/2``
    looked applied, and so did ``x=9`` of that same all-or-nothing command."""
    mm = _fleet("a", "b")

    def answer(verb_args: dict[str, int], states: dict[str, str], t: float) -> None:
        cid = mm.issue("params", t_exec=t, now=t, args=verb_args).command.command_id
        for drone, state in states.items():
            mm.on_status(drone, state=state, command_id=cid, now=t + 0.1,
                         info={"error": "unknown parameter"} if state == "error" else {})

    answer({"x": 5}, {"a": "done", "b": "done"}, T0)
    answer({"x": 9, "warp_speed": 2}, {"a": "error", "b": "error"}, T0 + 1)
    state = mm.state(now=T0 + 2)
    assert state["params"] == {"x": 5}
    assert state["params_rejected"] == {"x": 9, "warp_speed": 2}
    answer({"y": 1}, {"a": "done", "b": "error"}, T0 + 3)  # applied on one drone: in effect
    mm.issue("params", t_exec=T0 + 4, now=T0 + 4, args={"warp_speed": 3})  # not answered yet
    state = mm.state(now=T0 + 4.5)
    assert state["params"] == {"x": 5, "y": 1, "warp_speed": 3}
    assert state["params_rejected"] == {"x": 9}
