"""Incremental node evaluation agrees with the exact evaluator (eq. 4.1-4.7) along any path."""

from __future__ import annotations

import itertools

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.middleware.incremental import FixedItem, option_message
from tests.middleware.conftest import T0, msg, problem_of, small_spec
from utility_specs.evaluate import evaluate

SPEC = small_spec()
LAT = 0.1
H = T0 + 8.0


def _mission() -> list:
    out = []
    seq = 0
    for k in range(4):
        for sender in ("a", "b"):
            out.append(msg(sender, seq, "battery", T0 + 1.5 * k + (0.3 if sender == "b" else 0)))
            seq += 1
        out.append(msg("a", seq, "linear", T0 + 1.5 * k + 0.7))
        seq += 1
        out.append(msg("b", seq, "status", T0 + 1.5 * k + 0.9))
        seq += 1
        out.append(msg("a", seq, "image", T0 + 1.5 * k + 1.1))
        seq += 1
    return out


def _exact(problem, choices, fixed=()) -> float:  # type: ignore[no-untyped-def]
    received = [f.message.delivered(receiver="g", t_rcv=f.rcv_t) for f in fixed]
    for it, o in zip(problem.items, choices, strict=True):
        if o:
            received.append(option_message(it.message, o).delivered(receiver="g", t_rcv=it.rcv_t))
    base = evaluate([f.message.delivered(receiver="g", t_rcv=f.rcv_t) for f in fixed], SPEC,
                    t_start=T0 - 5, t_end=H).total
    return evaluate(received, SPEC, t_start=T0 - 5, t_end=H).total - base


@settings(max_examples=60, deadline=None)
@given(st.data())
def test_path_gain_equals_exact_evaluation(data: st.DataObject) -> None:
    messages = _mission()
    problem = problem_of(SPEC, messages, latency=LAT, horizon_end=H)
    # Images only in full version here: a newer message then dominates the older ones of its
    # stream, the Markovian case in which the chain is exact (see incremental.py).
    choices = [data.draw(st.integers(0, 1)) for i in range(problem.n)]
    exact = _exact(problem, choices)
    assert problem.path_gain(choices) == pytest.approx(exact, rel=1e-9, abs=1e-9)


def test_gain_with_a_fixed_base_message() -> None:
    """The newest already-sent message of a stream is the base every first send improves on."""
    base = msg("a", 99, "battery", T0 - 1.0)
    fixed = [FixedItem(message=base, send_t=base.t_gen, rcv_t=base.t_gen + LAT)]
    messages = [msg("a", 0, "battery", T0), msg("a", 1, "battery", T0 + 1.0)]
    problem = problem_of(SPEC, messages, latency=LAT, horizon_end=H, fixed=fixed)
    for choices in itertools.product((0, 1), repeat=2):
        assert problem.path_gain(choices) == pytest.approx(
            _exact(problem, choices, fixed), rel=1e-9, abs=1e-12
        )
    # battery (eq. 4.9): 1 - 0.2 (t - t_gen); the first message replaces the base from T0+0.1
    # until H: weight 2 * ∫ (0.2 * 1.0) dt over 7.9 s, both lines clipped at zero at expiry.
    expected = 2.0 * (_line(T0, T0 + LAT, H) - _line(T0 - 1.0, T0 + LAT, H))
    assert problem.path_gain([1, 0]) == pytest.approx(expected, rel=1e-12)


def _line(t_gen: float, a: float, b: float) -> float:
    end = min(b, t_gen + 5.0)
    if end <= a:
        return 0.0
    xa, xb = a - t_gen, end - t_gen
    return (xb - xa) - 0.1 * (xb * xb - xa * xa)


def test_a_lower_version_after_a_full_one_is_the_exact_pair_envelope() -> None:
    messages = [msg("a", 0, "image", T0), msg("a", 1, "image", T0 + 1.0)]
    problem = problem_of(SPEC, messages, latency=LAT, horizon_end=H)
    for choices in ([1, 3], [2, 3], [3, 1], [1, 2]):
        assert problem.path_gain(choices) == pytest.approx(_exact(problem, choices), rel=1e-9)


def test_versions_are_options_with_their_sizes() -> None:
    problem = problem_of(SPEC, [msg("a", 0, "image", T0)], horizon_end=H)
    assert int(problem.nopt[0]) == 4
    assert [int(problem.size[0, o]) for o in range(4)] == [0, 4000, 1000, 250]
    gains = [float(problem.gain[0, o, 0]) for o in (1, 2, 3)]
    assert gains[0] == pytest.approx(2 * gains[1]) == pytest.approx(4 * gains[2])  # eq. 4.33


def test_feasibility_matches_window_definition() -> None:
    messages = [msg("a", k, "linear", T0 + 0.4 * k, size=100) for k in range(4)]
    problem = problem_of(SPEC, messages, horizon_end=H, budget_bytes=200, window_s=1.0)
    assert problem.feasible([1, 1, 0, 1])  # sends at 0, 0.4, 1.2: window [0, 1] holds 200 B
    assert not problem.feasible([1, 1, 1, 0])  # 0, 0.4, 0.8 in one window: 300 B
