"""Planning for the spec's streams nobody has heard of yet (``plan_unheard_s``, issue 18)."""

from __future__ import annotations

import pytest

from companion.middleware import ConstantConstraint, Middleware, MiddlewareConfig, MiddlewareError
from companion.middleware.unheard import UNHEARD_PREFIX, UnheardStreams
from sitl.study.baselines import run_one
from utility_specs.files import builtin_spec
from utility_specs.message import Message

SPEC = builtin_spec("sim_mostly_low")  # agent i sends battery_i, weight 3^(i+1)
DATA = {"level": 1.0, "depletion_rate": 0.2}


def _battery(i: int, seq: int, t: float, **kw: float) -> Message:
    return Message(sender=f"agent{i}", seq=seq, type=f"battery_{i}", t_gen=t, size=2048,
                   data=DATA, **kw)


def _agent5(plan_unheard_s: float | None) -> Middleware:
    """agent5 (weight 729) has heard agent1 (weight 9) twice; the window takes 3 messages."""
    config = MiddlewareConfig(spec=SPEC, agent="agent5", max_iterations=300, horizon_s=5.0,
                              plan_unheard_s=plan_unheard_s)
    mw = Middleware(config, constraint=ConstantConstraint(limit_bytes_per_s=3 * 2048 / 2.5,
                                                          window_s=2.5))
    mw.decide(_battery(5, 0, 0.5), 0.5)  # sent: the window is empty
    mw.on_delivered([_battery(1, k, t, t_sent=t, t_rcv=t + 0.01)
                     for k, t in enumerate((0.0, 1.0))], 1.02)
    return mw


def test_the_tree_plans_for_every_type_nobody_was_heard_sending() -> None:
    """agent5 has heard of its own stream and agent1's: the other eight types of the spec
    are planned for (as ``?battery_i`` streams) with ``plan_unheard_s``, not without."""
    mw = _agent5(None)
    mw.decide(_battery(5, 1, 1.5), 1.5)
    assert not any(it.message.sender.startswith(UNHEARD_PREFIX)
                   for it in mw.last_problem.items)  # type: ignore[union-attr]
    mw = _agent5(60.0)
    mw.decide(_battery(5, 1, 1.5), 1.5)
    senders = {it.message.sender for it in mw.last_problem.items}  # type: ignore[union-attr]
    assert {UNHEARD_PREFIX + f"battery_{i}" for i in (0, 2, 3, 4, 6, 7, 8, 9)} <= senders
    assert "?battery_1" not in senders and "?battery_5" not in senders


def test_unheard_streams_stop_after_plan_unheard_s() -> None:
    mw = _agent5(1.2)  # first decision at 0.5: planning for unheard types ends at 1.7
    mw.decide(_battery(5, 1, 1.5), 1.5)
    assert any(it.message.sender.startswith(UNHEARD_PREFIX)
               for it in mw.last_problem.items)  # type: ignore[union-attr]
    mw.decide(_battery(5, 2, 2.5), 2.5)
    assert not any(it.message.sender.startswith(UNHEARD_PREFIX)
                   for it in mw.last_problem.items)  # type: ignore[union-attr]


def test_unheard_forecast_needs_a_period_and_a_template() -> None:
    streams = UnheardStreams()
    assert streams.items(SPEC, now=0.0, horizon_end=5.0, period_s=1.0, latency_s=0.0) == []
    streams.observe(SPEC, _battery(2, 0, 0.0))
    assert streams.items(SPEC, now=0.0, horizon_end=5.0, period_s=None, latency_s=0.0) == []
    items = streams.items(SPEC, now=0.0, horizon_end=2.0, period_s=1.0, latency_s=0.1)
    # 9 unheard types, at 0.5 and 1.5 each, with the template's data and size
    assert len(items) == 18
    assert sorted({it.send_t for it in items}) == [0.5, 1.5]
    assert all(it.message.data == DATA and it.message.size == 2048 for it in items)
    assert all(it.rcv_t == pytest.approx(it.send_t + 0.1) for it in items)
    with pytest.raises(MiddlewareError):
        MiddlewareConfig(spec=SPEC, agent="a", plan_unheard_s=0.0)


def test_zero_planned_violations_without_the_starvation_loss() -> None:
    """The fig. 5.7 fleet at its tightest budget (2.5 messages per window, 20 s, seed 1):
    without announcing over the budget no send is over it in the sender's knowledge, and
    planning for unheard types recovers part of what that cost (measured: 67.3 against
    63.4 %; the default, announcing over the budget, 67.2 %)."""
    plain = run_one("mostly-low", "mcts300", 2.5, seed=1, t_end=20.0)
    assert plain["known_over_budget"] > 0  # the default announces over the budget
    import companion.middleware.middleware as mwmod

    orig = mwmod.MiddlewareConfig.__init__

    def runs(**kw: object) -> dict[str, float]:
        def config(self: object, *a: object, **k: object) -> None:
            orig(self, *a, **{**k, **kw})  # type: ignore[arg-type]
        mwmod.MiddlewareConfig.__init__ = config  # type: ignore[method-assign]
        try:
            return run_one("mostly-low", "mcts300", 2.5, seed=1, t_end=20.0)
        finally:
            mwmod.MiddlewareConfig.__init__ = orig  # type: ignore[method-assign]

    off = runs(announce_over_budget=False)
    unheard = runs(announce_over_budget=False, plan_unheard_s=60.0)
    assert off["known_over_budget"] == unheard["known_over_budget"] == 0
    assert unheard["utility_pct"] > off["utility_pct"] + 2.0
