"""The overshoot margin (issue 18): learned from windows whose sends have all arrived."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.middleware import ConstantConstraint, Middleware, MiddlewareConfig
from companion.middleware.margin import OvershootMargin
from utility_specs.files import builtin_spec
from utility_specs.message import Message

BUDGET = 10_000.0
WINDOW = 2.5


def test_overshoot_of_a_settled_window_raises_the_margin_by_half_its_share() -> None:
    margin = OvershootMargin()
    # 12 kB sent in (0.5, 3.0]: 20 % over a 10 kB window budget
    sends = [(1.0, 6_000), (2.0, 6_000)]
    margin.observe(sends, now=4.0, settle_s=1.0, window_s=WINDOW, budget_bytes=BUDGET)
    assert margin.margin == pytest.approx(0.1, abs=1e-12)
    assert margin.plan_budget(BUDGET) == pytest.approx(9_000.0, abs=1e-6)


def test_a_window_not_yet_settled_is_not_judged() -> None:
    margin = OvershootMargin()
    # the window ends at now - settle = 1.5: the 9 kB sent at 2.0 may still be arriving
    margin.observe([(1.0, 6_000), (2.0, 9_000)], now=3.0, settle_s=1.5, window_s=WINDOW,
                   budget_bytes=BUDGET)
    assert margin.margin == 0.0


def test_each_window_end_is_used_once_per_quarter_window() -> None:
    margin = OvershootMargin()
    sends = [(1.0, 6_000), (2.0, 6_000)]
    margin.observe(sends, now=4.0, settle_s=1.0, window_s=WINDOW, budget_bytes=BUDGET)
    margin.observe(sends, now=4.2, settle_s=1.0, window_s=WINDOW, budget_bytes=BUDGET)
    # 0.2 s later: the same overshoot is not counted twice
    assert margin.margin == pytest.approx(0.1, abs=1e-12)


def test_the_margin_decays_only_over_windows_well_under_the_planning_budget() -> None:
    margin = OvershootMargin(margin=0.2)
    # 7.5 kB: under the 8 kB planning budget but not by the 15 % slack (6.8 kB)
    margin.observe([(1.0, 7_500)], now=4.0, settle_s=1.0, window_s=WINDOW, budget_bytes=BUDGET)
    assert margin.margin == 0.2
    margin.observe([(1.0, 1_000)], now=5.0, settle_s=1.0, window_s=WINDOW, budget_bytes=BUDGET)
    assert margin.margin == pytest.approx(0.19, abs=1e-12)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(0, 30), st.integers(1, 40_000)), max_size=40),
       st.lists(st.floats(0, 40), min_size=1, max_size=30))
def test_the_margin_stays_between_zero_and_its_ceiling(
        sends: list[tuple[float, int]], nows: list[float]) -> None:
    margin = OvershootMargin()
    for now in sorted(nows):
        margin.observe(sends, now=now, settle_s=0.5, window_s=WINDOW, budget_bytes=BUDGET)
        assert 0.0 <= margin.margin <= margin.ceiling
        assert BUDGET * (1 - margin.ceiling) <= margin.plan_budget(BUDGET) <= BUDGET


def _frame(sender: str, seq: int, t: float) -> Message:
    return Message(sender=sender, seq=seq, type="image", t_gen=t, size=4_000,
                   data={"red": 0.1})


def test_the_middleware_plans_with_the_learned_margin_only_when_asked() -> None:
    spec = builtin_spec("image_streaming")
    planned = {}
    for learn in (False, True):
        mw = Middleware(MiddlewareConfig(spec=spec, agent="uav1", max_iterations=50,
                                         learn_margin=learn),
                        rng=np.random.default_rng(0),
                        constraint=ConstantConstraint(limit_bytes_per_s=BUDGET / WINDOW,
                                                      window_s=WINDOW))
        # another drone sent 12 kB in one window (budget 10 kB), each frame arriving 0.3 s
        # after it was sent: by 5.0 the window (2.2, 4.7] has settled
        others = [replace(_frame("uav2", k, t), t_sent=t, t_rcv=t + 0.3)
                  for k, t in enumerate((3.0, 3.5, 4.0))]
        mw.on_delivered(others, now=4.5)
        mw.decide(_frame("uav1", 0, 5.0), 5.0)
        assert mw.last_problem is not None
        planned[learn] = mw.last_problem.budget_bytes
    assert planned[False] == BUDGET
    assert planned[True] == pytest.approx(9_000.0, abs=1e-6)  # 20 % over: a margin of half that


def test_study_policy_suffix_m_turns_the_margin_on() -> None:
    from sitl.study.baselines import _policy

    made = {name: _policy(name, 0.0, spec=builtin_spec("image_streaming"), agent="a",
                          index=0, seed=1, budget_bytes=1000.0, window_s=1.0, horizon_s=3.0)
            for name in ("mcts300", "mcts300m", "mcts600ksm", "mcts300ks")}
    got = {n: (p.config.max_iterations, p.config.knapsack_seed,  # type: ignore[union-attr]
               p.config.learn_margin)  # type: ignore[union-attr]
           for n, p in made.items()}
    assert got == {"mcts300": (300, False, False), "mcts300m": (300, False, True),
                   "mcts600ksm": (600, True, True), "mcts300ks": (300, True, False)}
