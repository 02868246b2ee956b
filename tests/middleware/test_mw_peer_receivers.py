"""The optimiser counts a peers type's utility at every receiver (issue 15, eq. 4.2)."""

from __future__ import annotations

import pytest

from companion.middleware.incremental import FixedItem, PlanItem, build_problem
from companion.middleware.knowledge import FleetKnowledge
from utility_specs.message import Message
from utility_specs.spec import parse_spec

POSITION = {"utility": "position", "aggregation": "max", "per_sender": True,
            "markovian": True, "params": {"v_max": 15.0, "area": 1.0e6}}


def spec(receivers: list[str]):
    return parse_spec({"mission": {"name": "p", "t_end": 100.0},
                       "types": {"position": {**POSITION, "receivers": receivers}}})


def pos(sender: str, seq: int, t: float, **kw) -> Message:
    return Message(sender=sender, seq=seq, type="position", t_gen=t, size=60,
                   data={"lat_deg": 47.0, "lon_deg": 8.0}, **kw)


def problem(s, receivers=None):
    items = [PlanItem(message=pos("a", 5, 10.0), send_t=10.0, rcv_t=10.05, kind="decide"),
             PlanItem(message=pos("a", 6, 11.0), send_t=11.0, rcv_t=11.05)]
    fixed = [FixedItem(message=pos("a", 1, 6.0), send_t=6.0, rcv_t=6.05)]
    return build_problem(s, items=items, fixed=fixed, horizon_end=13.0, budget_bytes=1e6,
                         window_s=1.0, receivers=receivers)


def test_gain_counts_once_per_receiver_with_the_same_base() -> None:
    s = spec(["ground", "peers"])
    one = problem(s)
    base = FixedItem(message=pos("a", 1, 6.0), send_t=6.0, rcv_t=6.05)
    three = problem(s, {("position", "a"): [base, base, base]})
    assert three.gain[:, 1:, :] == pytest.approx(3 * one.gain[:, 1:, :], rel=1e-9)
    assert one.gain[0, 1, 0] > 0


def test_a_receiver_holding_nothing_gains_more_than_one_holding_a_fresh_position() -> None:
    s = spec(["peers"])
    fresh = FixedItem(message=pos("a", 4, 9.5), send_t=9.5, rcv_t=9.55)
    stale = problem(s, {("position", "a"): [None]}).gain[0, 1, 0]
    held = problem(s, {("position", "a"): [fresh]}).gain[0, 1, 0]
    assert stale > held > 0
    # a slot inside the tree (the previous item sent) is the same at every receiver
    both = problem(s, {("position", "a"): [None, fresh]})
    assert both.gain[0, 1, 0] == pytest.approx(stale + held)
    single = problem(s, {("position", "a"): [None]})
    assert both.gain[1, 1, 1:] == pytest.approx(2 * single.gain[1, 1, 1:])


def test_ground_only_types_plan_for_one_receiver() -> None:
    k = FleetKnowledge(spec(["ground"]), agent="a", default_latency_s=0.05)
    k.on_delivered([pos("b", 1, 1.0).delivered(receiver="a", t_rcv=1.1)], now=1.1)
    view = k.view(pos("a", 1, 2.0), now=2.0, horizon_s=3.0, max_items=64, window_s=1.0)
    assert view.receivers == {}


def test_knowledge_lists_every_peer_with_what_it_reported() -> None:
    k = FleetKnowledge(spec(["ground", "peers"]), agent="a", default_latency_s=0.05)
    own = pos("a", 1, 1.0, t_sent=1.0)
    k.on_delivered([own.delivered(receiver="ground", t_rcv=1.05),
                    own.delivered(receiver="b", t_rcv=1.06),
                    pos("c", 1, 1.0).delivered(receiver="a", t_rcv=1.1)], now=1.2)
    view = k.view(pos("a", 2, 2.0), now=2.0, horizon_s=3.0, max_items=64, window_s=1.0)
    bases = view.receivers[("position", "a")]
    # ground, then peers b and c; c never reported: the ground's base stands in
    assert [b.message.seq if b else None for b in bases] == [1, 1, 1]
    assert bases[1] is not None and bases[1].rcv_t == 1.06
    assert k.peers_of("a") == ["b", "c"]
    assert k.peers_of("c") == ["a", "b"]
