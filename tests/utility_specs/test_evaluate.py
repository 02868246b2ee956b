"""The exact evaluator against hand-computed totals and a slow literal reference."""

from __future__ import annotations

import math
from dataclasses import replace
from itertools import groupby

import numpy as np
import pytest

from tests.utility_specs.helpers import info, msg, reference_integral, spec_of
from utility_specs.errors import MessageError
from utility_specs.evaluate import evaluate
from utility_specs.functions import (
    Battery,
    External,
    Linear,
    Localization,
    ObjectImage,
    Objective,
    Position,
    RedImage,
    Status,
    StatusPoisson,
    Video,
)
from utility_specs.message import Message, StateHistory, Version
from utility_specs.plots import utility_per_second


def total(info_type, messages, t_end, **kw):  # type: ignore[no-untyped-def]
    return evaluate(messages, spec_of(info_type), t_end=t_end, **kw).total


def test_sum_of_two_battery_messages_by_hand() -> None:
    fn = Battery(depletion_rate=0.1)
    a = msg(0.0, 1.0, seq=0, level=1.0)  # zero at 10
    b = msg(2.0, 3.0, seq=1, level=0.5)  # zero at 7
    # ∫_1^10 (1 - 0.1 t) dt = 9 - 0.05 (100 - 1) = 4.05
    # ∫_3^7 (1 - 0.2 (t - 2)) dt = 4 - 0.1 (25 - 1) = 1.6
    assert total(info(fn, "sum"), [a, b], 20.0) == pytest.approx(4.05 + 1.6)


def test_max_switches_where_two_battery_lines_cross() -> None:
    fn = Battery(depletion_rate=0.1)
    a = msg(0.0, 0.0, seq=0, level=1.0)  # 1 - 0.1 t
    b = msg(2.0, 2.0, seq=1, level=0.4)  # 1 - 0.25 (t - 2): crosses a at t = 10/3
    # [0,2]: a -> 2 - 0.2 = 1.8; [2, 10/3]: b; [10/3, 10]: a
    part1 = 1.8
    part2 = (10 / 3 - 2) - 0.125 * ((10 / 3 - 2) ** 2)
    part3 = (10 - 10 / 3) - 0.05 * (100 - (10 / 3) ** 2)
    assert total(info(fn, "max"), [a, b], 20.0) == pytest.approx(part1 + part2 + part3)


def test_last_leaves_a_gap_until_the_newest_generated_arrives() -> None:
    fn = Status()
    a = msg(0.0, 1.0, seq=0)
    b = msg(4.0, 6.0, seq=1)  # generated at 4, arrives at 6: [4, 6] is a gap
    lost = msg(5.0, None, seq=2)  # never received: does not exist for the receiver
    assert total(info(fn, "last"), [a, b, lost], 10.0) == pytest.approx(3.0 + 4.0)


def test_a_message_received_after_the_end_does_not_count() -> None:
    fn = Status()
    assert total(info(fn, "sum"), [msg(0.0, 11.0)], 10.0) == 0.0


def test_a_better_version_received_later_replaces_the_earlier_one() -> None:
    fn = Video(S=0.1, f_max=24.0, f_1=12.0)
    versions = (Version(name="full", size=1000, quality=1.0), Version(name="half", size=300,
                                                                        quality=0.5))
    base = Message(sender="a", receiver="g", seq=0, type="x", t_gen=0.0, versions=versions)
    half = Message(**{**_fields(base), "version": 1, "t_rcv": 0.5})
    full = Message(**{**_fields(base), "version": 0, "t_rcv": 1.0})
    expected = 0.5 * fn.integral(full, 0.5, 1.0) + fn.integral(full, 1.0, 10.0)
    for aggregation in ("sum", "max", "last"):
        got = total(info(fn, aggregation), [half, full], 10.0)
        assert got == pytest.approx(expected), aggregation
    # a worse version arriving after the best one changes nothing
    late_half = Message(**{**_fields(base), "version": 1, "t_rcv": 2.0})
    assert total(info(fn, "sum"), [half, full, late_half], 10.0) == pytest.approx(expected)


def test_a_replaced_copy_hands_over_to_its_successor_without_a_gap() -> None:
    """Quality does not change a status: the successor equals the copy it replaces."""
    versions = (Version(name="full", size=100, quality=1.0), Version(name="low", size=10,
                                                                       quality=0.25))
    base = Message(sender="a", receiver="g", seq=0, type="x", t_gen=0.0, versions=versions)
    low = Message(**{**_fields(base), "version": 1, "t_rcv": 1.0})
    full = Message(**{**_fields(base), "version": 0, "t_rcv": 2.0})
    assert total(info(Status(), "max"), [low, full], 5.0) == pytest.approx(4.0)
    fn = Battery(depletion_rate=0.1)
    low, full = (replace(m, data={"level": 1.0}) for m in (low, full))
    assert total(info(fn, "max"), [low, full], 5.0) == pytest.approx(fn.integral(full, 1.0, 5.0))


def _fields(m: Message) -> dict[str, object]:
    return {f: getattr(m, f) for f in m.__dataclass_fields__}


def test_external_counts_each_value_once_at_reception() -> None:
    fn = External()
    messages = [msg(0.0, 1.0, seq=0, value=2.0), msg(1.0, 3.0, seq=1, value=0.5),
                msg(1.0, 12.0, seq=2, value=9.0)]
    assert total(info(fn, "sum"), messages, 10.0) == pytest.approx(2.5)


def test_weights_receivers_and_per_sender_streams() -> None:
    fn = Position(v_max=1.0, area=100.0)
    per_sender = info(fn, "max", per_sender=True, weight=2.0)
    pooled = info(fn, "max", per_sender=False, weight=2.0)
    messages = [msg(0.0, 0.0, sender="a"), msg(0.0, 0.0, sender="b"),
                msg(0.0, 1.0, sender="a", receiver="h")]
    one = fn.integral(messages[0], 0.0, 10.0)
    result = evaluate(messages, spec_of(per_sender), t_end=10.0)
    assert result.total == pytest.approx(2 * (2 * one + fn.integral(messages[2], 1.0, 10.0)))
    assert result.per_receiver["g"] == pytest.approx(4 * one)
    assert result.per_type["x"] == pytest.approx(result.total)
    # pooled, the two senders' identical messages at g count once (max)
    pooled_total = evaluate(messages, spec_of(pooled), t_end=10.0).per_receiver["g"]
    assert pooled_total == pytest.approx(2 * one)


def test_unknown_type_is_an_error_unless_ignored() -> None:
    spec = spec_of(info(Status(), "last"))
    with pytest.raises(MessageError, match="'nope'"):
        evaluate([msg(0.0, 1.0, type="nope")], spec, t_end=5.0)
    assert evaluate([msg(0.0, 1.0, type="nope")], spec, t_end=5.0,
                    ignore_unknown_types=True).total == 0.0


def test_figure_4_9_halving_the_rate_at_f1_costs_S() -> None:
    fn = Video(S=0.1, f_max=24.0, f_1=12.0)
    assert utility_per_second(fn, 24.0) == pytest.approx(1.0)
    assert utility_per_second(fn, 48.0) == pytest.approx(1.0)
    halving_cost = utility_per_second(fn, 12.0) - utility_per_second(fn, 6.0)
    assert halving_cost == pytest.approx(0.1, abs=1e-9)
    # closed form of the per-second utility below f_max (derived from eq. 4.28):
    # u(f) = 1 - k log2(f_max / f) + k (1 - f / f_max) / ln 2
    for f in (1.0, 3.0, 8.0):
        expected = 1 - fn.k * math.log2(24 / f) + fn.k * (1 - f / 24) / math.log(2)
        assert utility_per_second(fn, f) == pytest.approx(expected, rel=1e-9)


# --- the exact evaluator against the literal definition, integrated numerically -------------

STEP = 1e-3


def _random_stream(rng: np.random.Generator, n: int, t_end: float, **data_fn) -> list[Message]:  # type: ignore[no-untyped-def]
    out = []
    for i in range(n):
        g = float(rng.uniform(0, t_end * 0.8))
        delay = float(rng.exponential(1.0))
        r = g + delay if rng.random() > 0.2 else None
        data = {k: f(rng) for k, f in data_fn.items()}
        out.append(msg(g, r, seq=i, **data))
    return out


CASES = [
    ("battery-max", info(Battery(depletion_rate=0.05), "max"),
     {"level": lambda r: float(r.uniform(0.2, 1.0))}),
    ("battery-sum", info(Battery(depletion_rate=0.05), "sum"),
     {"level": lambda r: float(r.uniform(0.2, 1.0))}),
    ("linear-max", info(Linear(), "max"),
     {"initial": lambda r: float(r.uniform(0.5, 3.0)),
      "slope": lambda r: float(r.uniform(0.05, 1))}),
    ("position-max", info(Position(v_max=1.0, area=300.0), "max"), {}),
    ("status-last", info(Status(), "last"), {}),
    ("poisson-max", info(StatusPoisson(rate=0.3), "max"), {}),
    ("video-max", info(Video(S=0.1, f_max=4.0, f_1=2.0), "max"), {}),
    ("red-max", info(RedImage(alpha=10.0, S=0.1, f_max=4.0, f_1=2.0), "max"),
     {"red": lambda r: float(r.choice([0.0, 0.05, 0.3, 1.0]))}),
    ("object-last", info(ObjectImage(alpha=3.0, S=0.2, f_max=2.0, f_1=1.0), "last"),
     {"object": lambda r: bool(r.random() < 0.3)}),
]


@pytest.mark.parametrize("name,info_type,data", CASES, ids=[c[0] for c in CASES])
@pytest.mark.parametrize("seed", [1, 2])
def test_exact_matches_the_literal_definition(name, info_type, data, seed) -> None:  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(seed)
    t_end = 20.0
    messages = _random_stream(rng, 12, t_end, **data)
    exact = total(info_type, messages, t_end)
    reference = reference_integral(info_type, messages, t_end, step=STEP)
    # midpoint rule: each jump (reception) costs at most STEP * max value
    assert exact == pytest.approx(reference, abs=40 * STEP * max(1.0, exact / t_end))


def test_state_dependent_objective_matches_the_literal_definition() -> None:
    fn = Objective()
    history = StateHistory([(0.0, {"objectives": []}), (1.0, {"objectives": ["o1"]}),
                            (7.0, {"objectives": ["o1", "o2"]}), (9.0, {"objectives": ["o2"]}),
                            (12.0, {"objectives": ["o2", "o3"]})])
    messages = [msg(0.2, 0.6, seq=0, objective="o1"), msg(5.0, 5.5, seq=1, objective="o2"),
                msg(10.0, 11.0, seq=2, objective="o3")]
    # thesis fig. 4.6: o1 on [1, 9], o2 on [7, 20], o3 on [12, 20]
    result = total(info(fn, "sum"), messages, 20.0, states={"g": history})
    assert result == pytest.approx(8 + 13 + 8)
    assert result == pytest.approx(
        reference_integral(info(fn, "sum"), messages, 20.0, history=history), abs=0.02
    )


def test_localization_total_matches_the_literal_definition() -> None:
    fn = Localization()
    history = StateHistory(
        [(float(t), {"observed_cells": [[c, 0] for c in range(t, t + 4)]}) for t in range(10)]
    )
    messages = [msg(0.0, 0.5, seq=0, cells=[[c, 0] for c in range(0, 6)]),
                msg(1.0, 2.5, seq=1, cells=[[c, 0] for c in range(4, 10)]),
                msg(3.0, 4.5, seq=2, cells=[[c, 0] for c in range(8, 14)])]
    exact = total(info(fn, "sum"), messages, 10.0, states={"g": history})
    reference = reference_integral(info(fn, "sum"), messages, 10.0, history=history)
    assert exact == pytest.approx(reference, abs=0.02)
    # with full coverage the sum of shares is 1 wherever the map covers the view
    assert exact == pytest.approx(9.5, abs=1e-9)


def test_a_better_version_of_a_map_keeps_its_new_area() -> None:
    """Eq. 4.20 and 4.33: a replacement copy covers the area its message covered, so the map
    loses nothing when the full version arrives."""
    fn = Localization()
    history = StateHistory([(0.0, {"observed_cells": [[c, 0] for c in range(4)]})])
    versions = (Version(name="full", size=100, quality=1.0), Version(name="low", size=10,
                                                                       quality=0.25))
    low = replace(msg(0.0, 1.0, seq=0, cells=[[c, 0] for c in range(4)]), versions=versions,
                  version=1)
    full = replace(low, version=0, t_rcv=3.0)
    for aggregation in ("sum", "max", "last"):
        got = total(info(fn, aggregation), [low, full], 10.0, states={"g": history})
        assert got == pytest.approx(9.0), aggregation
        assert got == pytest.approx(reference_integral(info(fn, aggregation), [low, full], 10.0,
                                                       history=history), abs=0.01)


LONG_VERSIONS = (Version(name="full", size=100, quality=1.0),
                 Version(name="half", size=40, quality=0.5),
                 Version(name="quarter", size=10, quality=0.25))
LONG_CASES = [
    ("battery", Battery(depletion_rate=0.05), lambda r, t: {"level": 1.0 - 0.004 * t}),
    ("linear", Linear(), lambda r, t: {"initial": float(r.uniform(0.5, 3.0)),
                                       "slope": float(r.uniform(0.05, 1.0))}),
    ("position", Position(v_max=1.0, area=300.0), lambda r, t: {}),
    ("poisson", StatusPoisson(rate=0.3), lambda r, t: {}),
    ("status", Status(), lambda r, t: {}),
    ("video", Video(S=0.1, f_max=5.0, f_1=2.5), lambda r, t: {}),
    ("red", RedImage(alpha=10.0, S=0.1, f_max=5.0, f_1=2.5),
     lambda r, t: {"red": float(r.choice([0.0, 0.01, 0.2, 0.5, 1.0]))}),
]


@pytest.mark.parametrize("name,fn,data", LONG_CASES, ids=[c[0] for c in LONG_CASES])
@pytest.mark.parametrize("seed", [5, 6])
def test_compiled_sweep_agrees_with_the_curve_sweep(name, fn, data, seed) -> None:  # type: ignore[no-untyped-def]
    """Two independent paths of eq. 4.5 on long streams, with better versions arriving late."""
    import sys

    core = sys.modules["utility_specs.evaluate"]
    if not core.JIT:
        pytest.skip("numba is not installed: the compiled sweep is off (pip install numba)")
    rng = np.random.default_rng(seed)
    copies = []
    t = 0.0
    for seq in range(300):
        t += float(rng.uniform(0.05, 0.6))
        first = msg(t, t + float(rng.exponential(0.3)), seq=seq, **data(rng, t))
        first = replace(first, versions=LONG_VERSIONS, version=int(rng.integers(1, 3)))
        copies.append(first)
        if rng.random() < 0.3:  # the full version follows and replaces the first copy
            assert first.t_rcv is not None
            copies.append(replace(first, version=0, t_rcv=first.t_rcv + float(rng.uniform(0, 3))))
    t_end = t + 5.0
    occs = [o for _, group in groupby(copies, key=lambda m: m.key)
            for o in core.occurrences(group)]
    assert any(o.until < math.inf for o in occs)
    compiled = core.evaluate_stream(info(fn, "max"), occs, t_start=1.0, t_end=t_end)
    for o in occs:
        o.curve = fn.curve(o.m)
    sweep = core._max_with_versions(sorted(occs, key=lambda o: o.start), 1.0, t_end)
    assert compiled == pytest.approx(sweep, rel=1e-12)
    assert compiled > 0
