"""The vectorised crossing-pair gains equal the scalar exact envelope (eq. 4.5) pair by pair."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.middleware.incremental import (
    _crossing_gains,
    _pair_gain,
    _Variant,
    build_problem,
    option_message,
)
from tests.middleware.conftest import T0, msg, problem_of, small_spec
from utility_specs.curves import ShapeCurve
from utility_specs.spec import parse_spec

SPEC = small_spec()
RED_SPEC = parse_spec({
    "mission": {"name": "red"},
    "types": {"image": {"utility": "red_image", "aggregation": "max", "weight": 1.0,
                        "per_sender": True, "markovian": False,
                        "params": {"alpha": 10.0, "S": 0.1, "f_max": 5.0, "f_1": 2.5}}},
})

_pair = st.tuples(
    st.floats(0.0, 3.0), st.floats(0.0, 1.0), st.integers(1, 3),  # p: t_gen, red, option
    st.floats(0.0, 2.0), st.floats(0.0, 1.0), st.integers(1, 3),  # j: t_gen - p's, ...
    st.floats(0.0, 0.5), st.floats(0.0, 0.5),  # latencies
)


def _variant(t_gen: float, red: float, option: int, latency: float) -> _Variant:
    m = option_message(msg("a", 0, "image", T0 + t_gen, red=red), option)
    info = RED_SPEC.types["image"]
    return _Variant(info, m, m.t_gen + latency)


@settings(max_examples=200, deadline=None)
@given(st.lists(_pair, min_size=1, max_size=8), st.floats(0.5, 6.0))
def test_crossing_gains_equal_the_scalar_pair_gain(pairs: list, horizon: float) -> None:
    ps = [_variant(gp, redp, op, lp) for gp, redp, op, _, _, _, lp, _ in pairs]
    js = [_variant(gp + dj, redj, oj, lj) for gp, _, _, dj, redj, oj, _, lj in pairs]
    shape = ps[0].curve.shape  # type: ignore[union-attr]
    assert isinstance(ps[0].curve, ShapeCurve)
    gains, moves = _crossing_gains(shape, ps, js, T0 + horizon)
    _assert_equal(ps, js, gains, moves, T0 + horizon)


def _assert_equal(ps: list[_Variant], js: list[_Variant], gains: np.ndarray,
                  moves: np.ndarray, horizon: float) -> None:
    for p, j, g, mv in zip(ps, js, gains, moves, strict=True):
        exact, exact_moves = _pair_gain(p, j, horizon)
        assert float(g) == pytest.approx(exact, rel=1e-9, abs=1e-9)
        if exact > 1e-9:
            assert bool(mv)
        if not exact_moves:
            assert not bool(mv)


def test_a_plain_quarter_frame_after_a_red_full_one_crosses_once() -> None:
    # red full frame at 0, plain quarter at 1 s: the quarter is worth more only once the
    # red frame has aged enough; the table entry is that positive part, exactly.
    messages = [msg("a", 0, "image", T0, red=0.5), msg("a", 1, "image", T0 + 1.0, red=0.0)]
    items = problem_of(RED_SPEC, messages, latency=0.1, horizon_end=T0 + 8.0).items
    problem = build_problem(RED_SPEC, items=items, fixed=[], horizon_end=T0 + 8.0,
                            budget_bytes=float("inf"), window_s=1.0)
    first = _Variant(RED_SPEC.types["image"], option_message(items[0].message, 1), T0 + 0.1)
    for o in (1, 2, 3):
        second = _Variant(RED_SPEC.types["image"], option_message(items[1].message, o), T0 + 1.1)
        expected, _ = _pair_gain(first, second, T0 + 8.0)
        assert float(problem.gain[1, o, 1]) == pytest.approx(expected, rel=1e-9, abs=1e-12)
    assert float(problem.gain[1, 3, 1]) < float(problem.gain[1, 3, 0])


def test_many_seeded_crossings_equal_the_scalar_pair_gain() -> None:
    rng = np.random.default_rng(3)
    ps, js = [], []
    for _ in range(400):
        gp = float(rng.uniform(0.0, 3.0))
        ps.append(_variant(gp, float(rng.uniform()), int(rng.integers(1, 4)),
                           float(rng.uniform(0.0, 0.5))))
        js.append(_variant(gp + float(rng.uniform(0.0, 2.0)), float(rng.uniform()),
                           int(rng.integers(1, 4)), float(rng.uniform(0.0, 0.5))))
    crossing = [
        k for k, (p, j) in enumerate(zip(ps, js, strict=True))
        if not j.curve.dominates(p.curve)  # type: ignore[union-attr, arg-type]
        and _pair_gain(p, j, T0 + 4.0)[0] > 1e-6
    ]
    assert len(crossing) > 50  # the case this code exists for is well covered
    shape = ps[0].curve.shape  # type: ignore[union-attr]
    gains, moves = _crossing_gains(shape, ps, js, T0 + 4.0)
    _assert_equal(ps, js, gains, moves, T0 + 4.0)
