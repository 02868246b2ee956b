"""Zero planned violations (issue 18, round 8): the fleet leaves room for the streams it has
not heard of instead of an unheard stream announcing itself over the budget.

Opt-in: ``announce_over_budget=False`` with ``plan_unheard_s`` and the declared fleet
(``fleet_size``, ``start_share_s=None``); docs/middleware.md "Round 8, announcements"
has the matrix and why it is not the default.
"""

from __future__ import annotations

import pytest

from companion.middleware import ConstantConstraint, MiddlewareConfig, MiddlewareError
from companion.middleware.unheard import UNHEARD_PREFIX, UnheardStreams
from tests.fig57_agents import SPEC, WINDOW_S, agent, battery, mission_start

ZERO = {"announce_over_budget": False, "plan_unheard_s": 5.0, "fleet_size": 10,
        "start_share_s": None}
"""The zero-planned-violations configuration of round 8, for the 10-agent fig. 5.7 fleet."""


def test_the_default_announces_the_heavy_stream_over_the_budget() -> None:
    """The old behaviour, and still the default: the light agent fills the window, the
    heavy one's first message goes out over it (a planned violation)."""
    _, heavy, light_sent, heavy_sent = mission_start()
    assert light_sent == 2 and heavy_sent
    assert heavy.counters["announce"] == 1 and heavy.counters["over_budget"] == 1


def test_the_light_agent_leaves_room_for_unheard_heavier_types_at_the_start() -> None:
    """Round 8: before any period is known the unheard types are forecast once per window,
    so the first speaker already plans for them; it drops its light message and the heavy
    stream goes out within the budget (the old code forecast nothing without a period:
    agent0 filled the window and agent9 overran it, or waited)."""
    light, heavy, light_sent, heavy_sent = mission_start(**ZERO)
    senders = {it.message.sender for it in light.last_problem.items}  # type: ignore[union-attr]
    assert {UNHEARD_PREFIX + f"battery_{i}" for i in range(1, 10)} <= senders
    assert light_sent == 0 and heavy_sent
    assert heavy.counters["over_budget"] == light.counters["over_budget"] == 0


def test_without_the_declared_fleet_room_mode_loses_the_heavy_message() -> None:
    """``announce_over_budget=False`` alone: no violation, but agent9 waits (the cost that
    kept it opt-in)."""
    _, heavy, light_sent, heavy_sent = mission_start(announce_over_budget=False)
    assert light_sent == 2 and not heavy_sent and heavy.counters["over_budget"] == 0


def test_a_declared_fleet_smaller_than_the_spec_plans_no_absent_types() -> None:
    """4 agents of a 10-type spec (the offline-optimum missions): six types are never flown,
    so an agent that cannot tell which would leave room for ghosts; it plans none."""
    mw = agent(0, **{**ZERO, "fleet_size": 4})
    mw.decide(battery(0, 0, 0.5), 0.5)
    assert not any(it.message.sender.startswith(UNHEARD_PREFIX)
                   for it in mw.last_problem.items)  # type: ignore[union-attr]


def test_plausible_unheard_types() -> None:
    streams = UnheardStreams()
    streams.observe(SPEC, battery(0, 0, 0.0))
    assert streams.plausible(SPEC, unheard_agents=None)  # no fleet: the spec is all there is
    assert streams.plausible(SPEC, unheard_agents=9)  # 9 unheard types, 9 unheard agents
    assert not streams.plausible(SPEC, unheard_agents=3)
    assert not streams.plausible(SPEC, unheard_agents=-1)


def test_start_share_s_none_turns_the_start_share_off() -> None:
    with pytest.raises(MiddlewareError):
        MiddlewareConfig(spec=SPEC, agent="a", start_share_s=-1.0)
    off = agent(0, fleet_size=10, start_share_s=None)
    on = agent(0, fleet_size=10)
    for mw in (off, on):  # a second message in the window: room for it only without the share
        mw.constraint = ConstantConstraint(limit_bytes_per_s=3 * 2048 / WINDOW_S,
                                           window_s=WINDOW_S)
    assert off.decide(battery(0, 0, 0.5), 0.5).send and on.decide(battery(0, 0, 0.5), 0.5).send
    assert off.decide(battery(0, 1, 1.5), 1.5).send
    assert not on.decide(battery(0, 1, 1.5), 1.5).send
