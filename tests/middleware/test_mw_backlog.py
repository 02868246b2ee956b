"""Issue 18: under a backlog the optimiser still decides (no greedy fallback), and simulated
links feed the adaptive constraint the way receiver reports do."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from companion.middleware.adaptive import AdaptiveConstraint
from companion.middleware.constraint import ConstantConstraint
from companion.middleware.incremental import PlanItem
from companion.middleware.knowledge import PlanningView, settle_inflight
from companion.middleware.middleware import Middleware, MiddlewareConfig
from sitl.netsim import ChannelConfig, SimAgent, StreamConfig, simulate
from utility_specs.files import builtin_spec
from utility_specs.message import Message, Version

SPEC = builtin_spec("image_streaming")
VERSIONS = (Version(name="full", size=40_000, quality=1.0),
            Version(name="half", size=10_000, quality=0.5),
            Version(name="quarter", size=2_500, quality=0.25))


def _image(sender: str, seq: int, t: float, red: float = 0.05) -> Message:
    return Message(sender=sender, seq=seq, type="image", t_gen=t, size=40_000,
                   data={"red": red}, versions=VERSIONS, version=0)


def test_a_backlog_of_other_agents_in_flight_messages_does_not_force_the_fallback() -> None:
    """Three other drones at 5 frames/s with 3 s latency put ~45 of their images in flight
    ahead of the decided one; with the companion's 300 iterations the old tree never reached
    the decided level (reason fallback-greedy)."""
    config = MiddlewareConfig(spec=SPEC, agent="a", max_iterations=300, horizon_s=3.0)
    mw = Middleware(config, constraint=ConstantConstraint(limit_bytes_per_s=75_000.0))
    reasons = []
    for k in range(60):  # 12 s of the fleet; the others' images arrive 3 s late
        t = 0.2 * k
        for other in ("b", "c", "d"):
            if t >= 3.0:
                m = replace(_image(other, k - 15, t - 3.0).with_version(2), t_sent=t - 3.0)
                mw.on_delivered([m.delivered(receiver="ground", t_rcv=t)], t)
        decision = mw.decide(_image("a", k, t), t)
        reasons.append(decision.reason)
    late = reasons[30:]
    assert late and all(r.startswith("mcts") for r in late), late
    assert mw.counters["fallback"] == 0


def _view(items: list[PlanItem]) -> PlanningView:
    return PlanningView(items=items, fixed=[], root_window=[(0.5, 1000)], horizon_end=10.0)


def test_settling_estimates_what_others_sent_in_the_last_lag_and_keeps_the_newest() -> None:
    inflight = [PlanItem(message=_image("b", i, 1.0 + 0.2 * i), send_t=1.0 + 0.2 * i,
                         rcv_t=4.0, kind="inflight") for i in range(4)]
    inflight.append(PlanItem(message=_image("c", 0, 1.5), send_t=1.5, rcv_t=4.0,
                             kind="inflight"))
    own = PlanItem(message=_image("a", 0, 2.0), send_t=2.0, rcv_t=2.1, kind="decide")
    view = settle_inflight(_view([*inflight, own]), now=2.0,
                           rates={"b": (10_000.0, 2500.0)}, lag_s=1.0)
    assert [it.kind for it in view.items] == ["decide"]
    # b: 10 kB/s of 2.5 kB messages over the last 1 s: 4 of them; c: no known rate
    assert view.root_window == [(0.5, 1000), (1.125, 2500), (1.375, 2500), (1.625, 2500),
                                (1.875, 2500)]
    kept = settle_inflight(_view([*inflight, own]), now=2.0, rates={}, lag_s=1.0, keep=2)
    assert [it.message.key[:2] for it in kept.items] == [("b", 3), ("c", 0), ("a", 0)]
    assert kept.root_window == [(0.5, 1000)]
    quiet = settle_inflight(_view([own]), now=2.0, rates={"b": (10_000.0, 2500.0)}, lag_s=0.0)
    assert quiet.root_window == [(0.5, 1000)] and quiet.items == [own]
    # 8 bytes' worth of a 2048-byte stream is no message (it blocked an exact fit)
    tiny = settle_inflight(_view([own]), now=2.0, rates={"b": (819.2, 2048.0)}, lag_s=0.01)
    assert tiny.root_window == [(0.5, 1000)]


def _fleet(make_policy: Any, n: int = 3) -> list[SimAgent]:
    def red(k: int, g: np.random.Generator) -> dict[str, Any]:
        return {"red": float(min(1.0, abs(g.normal(0.0, 0.05))))}

    return [SimAgent(name=f"uav{i}", policy=make_policy(f"uav{i}"), streams=[
        StreamConfig(type="image", period_s=0.2, size=40_000, phase_s=0.01 * i,
                     versions=VERSIONS, data=red),
        StreamConfig(type="position", period_s=1.0, size=64, phase_s=0.1 + 0.01 * i),
    ]) for i in range(n)]


@pytest.mark.parametrize("report_interval_s", [0.25, None])
def test_simulated_receiver_reports_feed_the_adaptive_constraint(
        report_interval_s: float | None) -> None:
    mws: list[Middleware] = []

    def policy(name: str) -> Middleware:
        config = MiddlewareConfig(spec=SPEC, agent=name, max_iterations=100, horizon_s=3.0)
        mws.append(Middleware(config, constraint=AdaptiveConstraint()))
        return mws[-1]

    result = simulate(_fleet(policy), t_end=6.0, rng=np.random.default_rng(1),
                      channel=ChannelConfig(capacity_bytes_per_s=125_000,
                                            report_interval_s=report_interval_s))
    own_delivered = {mw.config.agent: sum(1 for m in result.delivered
                                          if m.sender == mw.config.agent
                                          and m.t_rcv is not None and m.t_rcv <= 5.99)
                     for mw in mws}
    if report_interval_s is None:
        assert result.link_samples == 0
        assert all(mw.constraint.stats.counters["samples"] == 0 for mw in mws)
        return
    # every delivery reported at the latest one report interval later (the last may be pending)
    assert sum(own_delivered.values()) - 3 * 2 <= result.link_samples
    assert result.link_samples <= len(result.delivered)
    assert all(mw.constraint.stats.counters["samples"] > 0 for mw in mws)
    assert mws[0].counters["fallback"] == 0


def test_report_interval_must_be_positive() -> None:
    with pytest.raises(ValueError, match="report_interval_s"):
        ChannelConfig(report_interval_s=0.0)


def test_a_deadline_already_past_still_gets_a_tree_decision() -> None:
    """A loaded CPU can use up the time budget before the search starts: the tree still
    runs one chunk rather than leaving the decision to the greedy fallback."""
    config = MiddlewareConfig(spec=SPEC, agent="a", max_iterations=300, chunk_iterations=50)
    mw = Middleware(config, constraint=ConstantConstraint(limit_bytes_per_s=75_000.0),
                    budget_clock=lambda: 10.0)
    d = mw.decide(_image("a", 0, 0.0), 0.0, deadline=5.0)
    assert d.reason.startswith("mcts") and 0 < d.iterations <= 50
    assert mw.counters["fallback"] == 0


def test_without_overrun_an_announcement_never_overruns_the_known_window() -> None:
    """Issue 18: zero planned violations with ``announce_over_budget=False``. b's delivered
    reports fill the 1 s window (the history of test_an_invisible_stream_announces_itself_once):
    a's invisible stream waits for room instead of overrunning it, then goes out in budget."""
    from tests.middleware.conftest import T0, msg
    from tests.middleware.test_mw_middleware import _full_window_then_own, _mw

    mw = _mw(budget_bytes_per_s=250.0, announce_over_budget=False)
    assert [d.send for d in _full_window_then_own(mw)] == [False, False, False]
    assert mw.counters["over_budget"] == 0 and mw.counters["announce"] == 0
    later = mw.decide(msg("a", 200, "battery", T0 + 3.0), T0 + 3.0)
    assert later.send and mw.counters["over_budget"] == 0
