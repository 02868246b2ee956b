"""``status_change``: a repeated vehicle status is true until its state changes (eq. 4.14/4.16)."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.utility_specs.helpers import info, msg, reference_integral, spec_of
from utility_specs.curves import EndedCurve, ShapeCurve, StepCurve
from utility_specs.errors import MessageError, SpecError
from utility_specs.evaluate import evaluate
from utility_specs.functions import StatusChange, make_function
from utility_specs.spec import parse_spec

MISSIONS = Path(__file__).resolve().parents[2] / "utility_specs" / "missions"


def test_rate_zero_is_eq_4_14_a_step_from_reception() -> None:
    fn = StatusChange()
    m = msg(1.0, 2.0, since=0.5)
    assert isinstance(fn.curve(m), StepCurve)
    assert fn.value(m, 2.5) == 1.0
    assert fn.integral(m, 2.0, 5.0) == 3.0
    assert fn.params() == {"rate": 0.0}


def test_rate_is_eq_4_16_the_chance_the_state_has_not_changed() -> None:
    fn = StatusChange(rate=0.5)
    m = msg(1.0, 1.0, since=0.0)
    assert fn.value(m, 3.0) == pytest.approx(math.exp(-1.0), rel=1e-15)
    assert fn.integral(m, 1.0, 3.0) == pytest.approx((1 - math.exp(-1.0)) / 0.5, rel=1e-15)


def test_an_ended_state_is_worth_nothing_from_its_end_on() -> None:
    fn = StatusChange(rate=0.5)
    m = msg(1.0, 1.0, since=0.0, until=2.0)
    curve = fn.curve(m)
    assert isinstance(curve, EndedCurve) and curve.expiry == 2.0
    assert fn.value(m, 1.999) == pytest.approx(math.exp(-0.4995), rel=1e-12)
    assert fn.value(m, 2.0) == 0.0
    assert fn.integral(m, 1.0, 10.0) == pytest.approx((1 - math.exp(-0.5)) / 0.5, rel=1e-15)
    assert curve.knots() == (2.0,)


def test_superseded_ends_an_older_state_at_the_new_one_s_start() -> None:
    fn = StatusChange(rate=0.1)
    old = msg(1.0, 1.2, seq=1, since=0.0, mode="STABILIZE")
    same = msg(3.0, None, seq=2, since=0.0, mode="STABILIZE")
    new = msg(5.0, None, seq=3, since=4.5, mode="GUIDED")
    assert fn.superseded(old, same) is None  # a repeat: the old message stays true
    ended = fn.superseded(old, new)
    assert ended is not None and dict(ended.data) == {"since": 0.0, "mode": "STABILIZE",
                                                      "until": 4.5}
    assert fn.superseded(new, old) is None  # an older message tells nothing about a newer
    assert fn.superseded(ended, msg(9.0, None, seq=4, since=8.0)) is None  # ended already


def test_without_since_every_message_is_a_new_status_as_in_eq_4_14() -> None:
    fn = StatusChange()
    a, b = msg(1.0, 1.5, seq=1), msg(3.0, 3.25, seq=2)
    prepared = fn.prepare([a, b])
    assert prepared is not None
    assert [m.data.get("until") for m in prepared] == [3.0, None]


def test_prepare_derives_the_end_from_any_received_message_of_a_later_state() -> None:
    fn = StatusChange()
    a = msg(1.0, 1.5, seq=1, since=0.0)
    b = msg(2.0, 2.5, seq=2, since=0.0)  # the same state: no end
    c = msg(6.0, 6.5, seq=4, since=5.0)  # the change itself (seq 3) was lost
    prepared = fn.prepare([a, b, c])
    assert prepared is not None
    assert [m.data.get("until") for m in prepared] == [5.0, 5.0, None]
    never = msg(6.0, None, seq=4, since=5.0)  # a change never received ends nothing
    prepared = fn.prepare([a, b, never])
    assert prepared is not None
    assert [m.data.get("until") for m in prepared] == [None, None, None]


def test_evaluate_counts_a_state_only_while_it_is_true() -> None:
    """Exact totals over [0, 10]: a repeat adds nothing, a change replaces an ended state."""
    spec = spec_of(info(StatusChange(), "max", per_sender=True))
    a = msg(1.0, 1.5, seq=1, since=1.0)
    repeat = msg(3.0, 3.5, seq=2, since=1.0)
    change = msg(6.0, 7.0, seq=3, since=6.0)
    assert evaluate([a], spec, t_end=10.0).total == pytest.approx(8.5)
    assert evaluate([a, repeat], spec, t_end=10.0).total == pytest.approx(8.5)
    # [1.5, 6) the first state, nothing known of the new one until 7, then [7, 10]
    assert evaluate([a, repeat, change], spec, t_end=10.0).total == pytest.approx(4.5 + 3.0)
    late = msg(6.0, 9.0, seq=3, since=6.0)
    assert evaluate([a, late], spec, t_end=10.0).total == pytest.approx(4.5 + 1.0)


def test_dominance_of_a_new_state_over_an_ended_one() -> None:
    fn = StatusChange(rate=0.1)
    ended = fn.curve(msg(1.0, 1.1, since=0.0, until=4.0))
    new = fn.curve(msg(4.0, 4.1, since=4.0))
    assert isinstance(new, ShapeCurve)
    assert new.dominates(ended) and not ended.dominates(new)
    assert fn.curve(msg(5.0, 5.0, since=4.0, until=9.0)).dominates(
        fn.curve(msg(4.5, 4.6, since=4.0, until=9.0)))


def test_bad_data_and_params_are_clear_errors() -> None:
    with pytest.raises(MessageError, match=r"since 5\.0 is after its t_gen 1\.0"):
        StatusChange().curve(msg(1.0, 1.0, since=5.0))
    with pytest.raises(MessageError, match="'since' must be a finite number"):
        StatusChange().curve(msg(1.0, 1.0, since="soon"))
    with pytest.raises(SpecError, match="rate"):
        make_function("status_change", {"rate": -1.0})


@pytest.mark.parametrize("name", ["image_streaming", "kpk_reconstruction", "telemetry"])
def test_every_shipped_spec_with_a_vehicle_status_uses_status_change(name: str) -> None:
    spec = parse_spec(tomllib.loads((MISSIONS / f"{name}.toml").read_text()))
    status = spec.types["status"]
    assert isinstance(status.utility, StatusChange)
    assert (status.aggregation, status.utility.rate) == ("max", 0.1)


@settings(max_examples=25, deadline=None)
@given(
    rate=st.sampled_from([0.0, 0.3]),
    stream=st.lists(st.tuples(st.integers(0, 32), st.booleans(), st.integers(0, 8),
                              st.booleans()), min_size=1, max_size=8),
)
def test_exact_evaluation_matches_the_literal_definition(
        rate: float, stream: list[tuple[int, bool, int, bool]]) -> None:
    """Repeats and changes of state, delays, losses: the exact sweep over ended curves equals
    the midpoint rule over A(M, t) read from the definition (eq. 4.5 with ``prepare``)."""
    fn = StatusChange(rate=rate)
    messages, since = [], 0.0
    for seq, (k, change, delay, lost) in enumerate(sorted(stream)):
        t_gen = 0.25 * k
        if change or seq == 0:
            since = t_gen
        messages.append(msg(t_gen, None if lost else t_gen + 0.125 * delay, seq=seq,
                            since=since))
    t_end = 10.0
    spec = spec_of(info(fn, "max", per_sender=True))
    exact = evaluate(messages, spec, t_end=t_end).total
    step = 5e-3
    literal = reference_integral(info(fn, "max", per_sender=True), messages, t_end, step=step)
    assert exact == pytest.approx(literal, abs=4 * step * (len(messages) + 1))
