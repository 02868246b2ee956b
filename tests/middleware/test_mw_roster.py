"""A declared roster (issue 18, round 9): which agent generates which types.

With it the fleet plans exactly for the streams it has not heard yet, under the agent that
will send them, and announcements never go over the known window (zero planned
violations). docs/middleware.md "Round 9, a declared roster" has the measurements.
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from companion.middleware import ConstantConstraint, Middleware, MiddlewareConfig, MiddlewareError
from companion.middleware.unheard import UNHEARD_PREFIX
from tests.fig57_agents import SPEC, agent, battery, mission_start
from tests.processes import assert_one_line_error
from utility_specs.errors import SpecError
from utility_specs.files import builtin_spec
from utility_specs.message import Message
from utility_specs.spec import MissionSpec, parse_spec

TEN = {f"agent{i}": (f"battery_{i}",) for i in range(10)}


def _unheard(mw: Middleware) -> set[tuple[str, str]]:
    assert mw.last_problem is not None
    return {(it.message.sender, it.message.type) for it in mw.last_problem.items
            if it.message.sender.startswith(UNHEARD_PREFIX)}


def _unheard_times(mw: Middleware, sender: str) -> list[float]:
    assert mw.last_problem is not None
    return sorted(it.send_t for it in mw.last_problem.items if it.message.sender == sender)


def test_a_roster_plans_exactly_its_unheard_streams() -> None:
    """4 agents of a 10-type spec (the offline-optimum missions): round 8 could not tell
    which 3 of the 9 unheard types are flown and planned for none; the roster names them."""
    roster = {f"agent{i}": (f"battery_{i}",) for i in range(4)}
    mw = agent(0, roster=roster)
    mw.decide(battery(0, 0, 0.5), 0.5)
    assert _unheard(mw) == {(f"?agent{i}", f"battery_{i}") for i in (1, 2, 3)}
    mw.on_delivered([battery(2, 0, 0.6, t_sent=0.6).delivered(receiver="ground", t_rcv=0.7)],
                    0.7)
    mw.decide(battery(0, 1, 1.5), 1.5)
    assert _unheard(mw) == {("?agent1", "battery_1"), ("?agent3", "battery_3")}


def test_the_roster_in_the_mission_spec_is_used() -> None:
    spec = dataclasses.replace(SPEC, roster={"agent0": ("battery_0",), "agent5": ("battery_5",)})
    mw = agent(0, spec=spec)
    assert mw.config.declared_roster == spec.roster
    mw.decide(battery(0, 0, 0.5), 0.5)
    assert _unheard(mw) == {("?agent5", "battery_5")}


def test_the_unheard_planning_ends_after_plan_unheard_s() -> None:
    mw = agent(0, roster=TEN, plan_unheard_s=2.0)
    mw.decide(battery(0, 0, 0.5), 0.5)
    assert len(_unheard(mw)) == 9
    mw.decide(battery(0, 1, 3.0), 3.0)
    assert _unheard(mw) == set()


def _uav0_hearing_uav1s_frames(spec: MissionSpec, roster: dict[str, tuple[str, ...]]
                               ) -> Middleware:
    """uav0 decides three frames of its own while it hears three of uav1's, 0.2 s apart."""
    mw = Middleware(MiddlewareConfig(spec=spec, agent="uav0", max_iterations=100, horizon_s=3.0,
                                     roster=roster),
                    constraint=ConstantConstraint(limit_bytes_per_s=50_000, window_s=2.5))
    frame = {"red": 0.1, "object": False}
    for k in range(3):
        t = 0.2 * k
        mw.on_delivered([Message(sender="uav1", seq=k, type="image", t_gen=t, size=10_000,
                                 data=frame, t_sent=t).delivered(receiver="ground",
                                                                 t_rcv=t + 0.1)], t + 0.1)
        mw.decide(Message(sender="uav0", seq=k, type="image", t_gen=t + 0.05, size=10_000,
                          data=frame), t + 0.15)
    return mw


def test_streams_of_the_same_type_are_heard_per_agent() -> None:
    """Every drone of the product flies the same types: hearing uav1's frames says nothing
    about uav2's, which stay planned for (at the period of the known image stream)."""
    spec = builtin_spec("image_streaming")
    roster = {f"uav{i}": ("image", "position", "battery") for i in range(3)}
    mw = _uav0_hearing_uav1s_frames(spec, roster)
    unheard = _unheard(mw)
    assert ("?uav2", "image") in unheard and ("?uav1", "image") not in unheard
    assert ("?uav1", "position") not in unheard  # no position known: no data to plan with
    times = _unheard_times(mw, "?uav2")
    assert times[1] - times[0] == pytest.approx(0.2)



def test_with_a_roster_nothing_is_announced_over_the_budget() -> None:
    """The default announces agent9's stream over the window agent0 filled (a planned
    violation); with a roster (and the default ``announce_over_budget=True``) agent0 left
    room for it and it goes out within the budget."""
    _, heavy, _, heavy_sent = mission_start()
    assert heavy_sent and heavy.counters["over_budget"] == 1
    light, heavy, light_sent, heavy_sent = mission_start(roster=TEN)
    assert heavy_sent and light_sent < 2
    assert heavy.counters["over_budget"] == light.counters["over_budget"] == 0


def test_a_full_known_window_is_not_announced_over_with_a_roster() -> None:
    """agent9 knows of two sends filling the window and has never been heard: with a roster
    it waits (no planned violation) instead of announcing over them."""
    for roster, over in ((None, 1), (TEN, 0)):
        heavy = agent(9, roster=roster, plan_unheard_s=0.1)
        heavy.on_delivered([battery(i, 0, 0.5 + 0.1 * i, t_sent=0.5 + 0.1 * i).delivered(
            receiver="ground", t_rcv=0.6 + 0.1 * i) for i in (0, 1)], 0.8)
        heavy.decide(battery(9, 0, 0.9), 0.9)
        heavy.decide(battery(9, 1, 1.0), 1.0)
        assert heavy.counters["over_budget"] == over


def test_a_spec_roster_without_this_agent_is_refused() -> None:
    """The roster would plan the fleet no room for this agent's streams: a one-line error
    (the companion's setup error), not a silent misplan."""
    spec = dataclasses.replace(SPEC, roster={"agent5": ("battery_5",)})
    with pytest.raises(MiddlewareError) as exc:
        MiddlewareConfig(spec=spec, agent="agent0")
    assert str(exc.value) == ("mission spec 'sim_mostly_low': roster does not name this "
                              "agent (agent0)")


@pytest.mark.parametrize(("roster", "why"), [
    ({}, "roster must map"),
    ({"agent0": ()}, "roster.agent0: expected a non-empty list"),
    ({"agent0": ("battery_0", "battery_0")}, "distinct"),
    ({"agent0": ("image",)}, "'image' is not a type"),
    ({"agent0": "battery_0"}, "expected a non-empty list"),
    ({"?x": ("battery_0",), "agent0": ("battery_0",)}, "must be a non-empty string"),
    ({"agent1": ("battery_1",)}, "does not name this agent (agent0)"),
])
def test_a_bad_roster_is_one_line(roster: object, why: str) -> None:
    with pytest.raises(MiddlewareError) as exc:
        MiddlewareConfig(spec=SPEC, agent="agent0", roster=roster)  # type: ignore[arg-type]
    assert why in str(exc.value) and "\n" not in str(exc.value)


def _raw(roster: object) -> dict[str, object]:
    return {"mission": {"name": "m", "roster": roster},
            "types": {"battery": {"utility": "battery", "aggregation": "max",
                                   "params": {"depletion_rate": 0.01}}}}


def test_the_spec_parses_a_roster() -> None:
    spec = parse_spec(_raw({"uav0": ["battery"], "uav1": ["battery"]}), source="m.toml")
    assert spec.roster == {"uav0": ("battery",), "uav1": ("battery",)}
    assert "roster" not in spec.extra
    assert parse_spec(_raw(None) | {"mission": {"name": "m"}}).roster is None


@pytest.mark.parametrize(("roster", "key"), [
    ([], "mission.roster"),
    ({}, "mission.roster"),
    ({"uav0": []}, "mission.roster.uav0"),
    ({"uav0": ["image"]}, "mission.roster.uav0"),
    ({"uav0": "battery"}, "mission.roster.uav0"),
    ({"uav0": ["battery", "battery"]}, "mission.roster.uav0"),
    ({"?uav0": ["battery"]}, "mission.roster.?uav0"),
])
def test_a_bad_spec_roster_is_one_line(roster: object, key: str) -> None:
    with pytest.raises(SpecError) as exc:
        parse_spec(_raw(roster), source="m.toml")
    assert str(exc.value).startswith(f"m.toml: {key}: expected") and "\n" not in str(exc.value)


def test_no_announcement_takes_the_room_left_for_a_heavier_unheard_stream() -> None:
    """Round 9: while the roster's unheard streams are planned for, the fleet leaves this
    stream room, so it is not announced: agent6 (slow depletion, as in mostly-low 2.5 msgs/T
    seed 2), never heard, drops its message and leaves the window's last slot to the
    heavier unheard streams. Announcing it, as round 8's rule did, took the slot from
    agent9 (that seed sent agent6 at 0.55 and 3.35 s and agent9 first at 3.33 s)."""
    def battery(i: int, t: float, **kw: float) -> Message:
        return Message(sender=f"agent{i}", seq=0, type=f"battery_{i}", t_gen=t, size=2048,
                       data={"level": 1.0, "depletion_rate": 0.008}, **kw)

    mw = agent(6, roster=TEN)
    mw.on_delivered([battery(8, 0.32, t_sent=0.32).delivered(receiver="ground", t_rcv=0.33)],
                    0.33)
    decision = mw.decide(battery(6, 0.55), 0.55)
    assert not decision.send and mw.counters["announce"] == 0


def test_a_bad_roster_in_a_spec_file_is_one_line_from_the_cli(tmp_path: Path) -> None:
    """The real console script: a spec whose roster names a type it lacks."""
    spec = tmp_path / "bad_roster.toml"
    spec.write_text('[mission]\nname = "m"\n[mission.roster]\nuav0 = ["image"]\n'
                    '[types.battery]\nutility = "battery"\naggregation = "max"\n'
                    'params = { depletion_rate = 0.01 }\n')
    log = tmp_path / "log.jsonl"
    log.write_text("")
    tool = Path(sys.executable).parent / "uav-utility"
    result = subprocess.run([str(tool), "evaluate", "--spec", str(spec), str(log)],
                            capture_output=True, text=True, timeout=60, check=False)
    assert_one_line_error(result, 2, "mission.roster.uav0: expected types of this spec")


def test_an_unheard_stream_repeats_at_its_types_declared_period() -> None:
    """Round 15: at the mission's first message no period is known. With each type's
    nominal period declared (1 s, the fig. 5.7 agents' rate), agent9's unheard stream is
    forecast at it from half a period on, over the 5 s horizon. Undeclared (the shipped
    fig. 5.7 specs), it is once per window T (2.5 s): 2.5 times too few, and the first
    speakers filled the window."""
    declared = {name: dataclasses.replace(info, period_s=1.0)
                for name, info in SPEC.types.items()}
    mw = agent(0, spec=dataclasses.replace(SPEC, types=declared), roster=TEN)
    mw.decide(battery(0, 0, 0.5), 0.5)
    assert _unheard_times(mw, "?agent9") == pytest.approx([1.0, 2.0, 3.0, 4.0, 5.0])
    mw = agent(0, roster=TEN)
    mw.decide(battery(0, 0, 0.5), 0.5)
    assert _unheard_times(mw, "?agent9") == pytest.approx([1.75, 4.25])


def test_a_known_stream_of_the_type_outranks_the_declared_period() -> None:
    """uav1's frames show the image period (0.2 s): uav2's unheard image stream follows it,
    not the spec's declared 1 s."""
    base = builtin_spec("image_streaming")
    image = dataclasses.replace(base.types["image"], period_s=1.0)
    spec = dataclasses.replace(base, types={**base.types, "image": image})
    roster = {f"uav{i}": ("image",) for i in range(3)}
    mw = _uav0_hearing_uav1s_frames(spec, roster)
    times = _unheard_times(mw, "?uav2")
    assert len(times) > 3 and np.diff(times) == pytest.approx(0.2)


def _with_period(period: object) -> dict[str, object]:
    return {"mission": {"name": "m"},
            "types": {"battery": {"utility": "battery", "aggregation": "max", "period_s": period,
                                  "params": {"depletion_rate": 0.01}}}}


@pytest.mark.parametrize("period", [0, -1.0, "1", True, float("inf")])
def test_a_bad_period_is_one_line(period: object) -> None:
    with pytest.raises(SpecError) as exc:
        parse_spec(_with_period(period), source="m.toml")
    assert str(exc.value).startswith("m.toml: types.battery.period_s: expected a number > 0")
    assert "\n" not in str(exc.value)


def test_the_spec_parses_a_period() -> None:
    assert parse_spec(_with_period(2)).types["battery"].period_s == 2.0
    assert parse_spec(_raw(None) | {"mission": {"name": "m"}}).types["battery"].period_s is None
