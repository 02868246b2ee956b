"""Issue 18 round 8: other agents' future sends valued by expectation, out of the tree
(``MiddlewareConfig(expect_others=...)``, :mod:`companion.middleware.expected`)."""

from __future__ import annotations

import itertools
import tomllib

import numpy as np
import pytest

from companion.middleware.baselines import offline_optimum
from companion.middleware.constraint import ConstantConstraint
from companion.middleware.errors import MiddlewareError
from companion.middleware.expected import denser, expect_others
from companion.middleware.incremental import PlanItem, build_problem
from companion.middleware.knowledge import PlanningView
from companion.middleware.mcts import MCTS, greedy_option
from companion.middleware.middleware import Middleware, MiddlewareConfig
from utility_specs.message import Message
from utility_specs.spec import parse_spec

SPEC = parse_spec(tomllib.loads("""
[mission]
name = "expected"
[types.battery]
utility = "battery"
aggregation = "max"
per_sender = true
params = { depletion_rate = 0.5 }
[types.shared]
utility = "position"
aggregation = "max"
per_sender = false
params = { v_max = 15.0, area = 1e6 }
"""))


def _battery(sender: str, seq: int, t: float, size: int = 1000) -> Message:
    return Message(sender=sender, seq=seq, type="battery", t_gen=t, size=size,
                   data={"level": 1.0, "depletion_rate": 0.5})


def _item(sender: str, seq: int, t: float, kind: str = "forecast", size: int = 1000
          ) -> PlanItem:
    return PlanItem(message=_battery(sender, seq, t, size), send_t=t, rcv_t=t + 0.01, kind=kind)


def test_an_expected_send_counts_in_the_windows_only_from_its_send_time() -> None:
    """Budget one message per 1 s window; another agent is expected to send at t = 1.5. The
    own message at 0 fits (no window holds both), the one at 2 shares [1, 2] with it and
    does not. As a root-window entry (how every fixed send entered the windows before
    round 8) the expected send counted from the root and blocked the message at 0 too."""
    items = [_item("a", 0, 0.0, kind="decide"), _item("a", 1, 2.0)]
    for expected, root, want in (([(1.5, 1000)], [], 1), ([], [(1.5, 1000)], 0)):
        problem = build_problem(SPEC, items=items, fixed=[], horizon_end=4.0, budget_bytes=1000,
                                window_s=1.0, root_window=root, expected=expected)
        search = MCTS(problem, max_nodes=100)
        search.run(100)
        assert search.result().option == want
        assert greedy_option(problem, 0) == want
    problem = build_problem(SPEC, items=items, fixed=[], horizon_end=4.0, budget_bytes=1000,
                            window_s=1.0, expected=[(1.5, 1000)])
    assert problem.feasible([1, 0]) and not problem.feasible([1, 1])
    assert offline_optimum(problem).choices == (1, 0)


@pytest.mark.parametrize("strict", [False, True])
@pytest.mark.parametrize("seed", range(8))
def test_search_optimum_and_feasibility_agree_on_expected_sends(seed: int, strict: bool
                                                                ) -> None:
    """Small random problems (own messages, expected sends of others between them): the
    dynamic programme's optimum is the best feasible plan by enumeration, and no plan the
    search evaluates beats it (the kernel counts the expected sends as the two do)."""
    rng = np.random.default_rng(seed)
    times = np.sort(rng.uniform(0.0, 4.0, 7))
    items = [_item("a", k, float(t), kind="decide" if k == 0 else "forecast",
                   size=int(rng.choice([500, 1000, 1500]))) for k, t in enumerate(times)]
    expected = [(float(t), int(rng.choice([500, 1000]))) for t in rng.uniform(0.0, 4.0, 4)]
    problem = build_problem(SPEC, items=items, fixed=[], horizon_end=5.0, budget_bytes=2000,
                            window_s=1.0, expected=expected, expected_strict=strict)
    plans = [c for c in itertools.product((0, 1), repeat=problem.n) if problem.feasible(c)]
    best = max(problem.path_gain(c) for c in plans)
    exact = offline_optimum(problem)
    assert problem.feasible(exact.choices)
    assert exact.gain == pytest.approx(best, rel=1e-9)
    search = MCTS(problem, max_nodes=3000, best_plan=True, c=2.0)
    search.run(3000)
    assert float(search.best[0]) <= exact.gain * (1 + 1e-9)
    assert float(search.best[0]) >= 0.9 * exact.gain


def _view() -> PlanningView:
    items = [_item("a", 5, 10.0, kind="decide"), _item("b", 3, 9.9, kind="inflight"),
             _item("a", 6, 11.0), _item("a", 7, 12.0)]
    items += [_item("b", 4 + k, 10.2 + 0.5 * k) for k in range(6)]  # 6 forecasts in (10, 13]
    items += [_item("c", k, 10.4 + k) for k in range(3)]
    items.append(PlanItem(message=Message(sender="c", seq=9, type="shared", t_gen=10.6,
                                          size=100, data={}),
                          send_t=10.6, rcv_t=10.61))
    return PlanningView(items=sorted(items, key=lambda it: it.send_t), fixed=[], root_window=[],
                        horizon_end=13.0)


def test_the_others_forecasts_leave_the_tree_and_their_rate_joins_the_windows() -> None:
    """b sent 1000 B/s of 1000-byte messages: over the 3 s horizon three whole messages,
    evenly spread; c has no known rate: its forecasts leave and nothing is expected of it
    (a sender heard of but not sending). Own messages, the decided one, in-flight ones and
    a stream that couples senders (max, per_sender = false) stay levels."""
    view, expected = expect_others(_view(), SPEC, agent="a", now=10.0,
                                   rates={"b": (1000.0, 1000.0)}, mode="spread")
    assert expected == [(10.5, 1000), (11.5, 1000), (12.5, 1000)]
    left = {(it.message.sender, it.message.seq, it.kind) for it in view.items}
    assert left == {("a", 5, "decide"), ("b", 3, "inflight"), ("a", 6, "forecast"),
                    ("a", 7, "forecast"), ("c", 9, "forecast")}


def test_forecast_placement_uses_the_senders_forecast_times_and_keep_keeps_levels() -> None:
    view, expected = expect_others(_view(), SPEC, agent="a", now=10.0,
                                   rates={"b": (1000.0, 800.0)}, mode="forecast", keep={"c"})
    # round(1000 * 3 / 800) = 4 of b's 6 forecast times (10.2 10.7 11.2 11.7 12.2 12.7),
    # evenly chosen: indices 0, 2, 3, 5 (int((i + 0.5) * 6 / 4))
    assert expected == [(10.2, 800), (11.2, 800), (11.7, 800), (12.7, 800)]
    assert sum(it.message.sender == "c" for it in view.items) == 4  # kept: 3 forecasts + shared
    assert not any(it.message.sender == "b" and it.kind == "forecast" for it in view.items)


def test_the_decided_option_does_not_depend_on_the_others_forecast_levels() -> None:
    """With expected others no level of the tree is another agent's forecast message: the
    search chooses only this agent's messages, the others enter as expected bytes."""
    config = MiddlewareConfig(spec=SPEC, agent="a", max_iterations=300, horizon_s=3.0,
                              expect_others="forecast", search_inflight=0)
    mw = Middleware(config, constraint=ConstantConstraint(limit_bytes_per_s=2000.0))
    for k in range(20):
        t = 0.5 * k
        if k >= 2:
            sent = _battery("b", k - 2, t - 1.0).delivered(receiver="ground", t_rcv=t)
            mw.on_delivered([sent], t)
        mw.decide(_battery("a", k, t + 0.01), t + 0.01)
    problem = mw.last_problem
    assert problem is not None
    assert {it.message.sender for it in problem.items} == {"a"}
    assert len(problem.ahead_t) > 0 and np.all(problem.ahead_t > 9.51)


def test_an_unknown_mode_is_refused() -> None:
    with pytest.raises(MiddlewareError):
        MiddlewareConfig(spec=SPEC, agent="a", expect_others="everything")


def test_ranking_keeps_the_expected_sends_of_denser_streams_only() -> None:
    """Three senders, the same battery stream at 1 Hz, in 500 / 1000 / 4000-byte messages:
    what a message adds after the previous one is the same, per byte b's is twice a's and
    c's a quarter. Agent a counts b's expected sends, not c's (c, ranking the same way,
    counts a's)."""
    items = [_item(s, k, 10.0 + k + off, kind="decide" if (s, k) == ("a", 0) else "forecast",
                   size=size)
             for s, off, size in (("a", 0.0, 1000), ("b", 0.3, 500), ("c", 0.6, 4000))
             for k in range(3)]
    problem = build_problem(SPEC, items=items, fixed=[], horizon_end=13.0, budget_bytes=1e4,
                            window_s=1.0)
    rates = {"b": (500.0, 500.0), "c": (4000.0, 4000.0), "d": (10.0, 10.0)}
    assert denser(problem, rates, agent="a") == {"b": rates["b"], "d": rates["d"]}
    assert denser(problem, rates, agent="c") == rates  # everyone is denser than c


def test_demand_expects_every_forecast_message_in_the_size_the_sender_sends() -> None:
    """b is seen to send 600-byte messages (a smaller version): each of its six forecasts is
    expected in that size; c, never seen sending, in its forecasts' own size."""
    _, expected = expect_others(_view(), SPEC, agent="a", now=10.0, mode="demand",
                                rates={"b": (600.0, 600.0), "c": (0.0, 0.0)})
    assert expected == sorted([(10.2 + 0.5 * k, 600) for k in range(6)]
                              + [(10.4 + k, 1000) for k in range(3)])
