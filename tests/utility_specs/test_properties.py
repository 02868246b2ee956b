"""Properties of the model (hypothesis): monotonicity, order invariance, stream independence."""

from __future__ import annotations

from dataclasses import replace
from itertools import groupby

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.utility_specs.helpers import info, spec_of
from utility_specs.evaluate import (
    JIT,
    _compiled_max,
    _max_with_versions,
    evaluate,
    occurrences,
)
from utility_specs.functions import (
    Battery,
    Linear,
    Position,
    RedImage,
    Status,
    StatusPoisson,
    Video,
)
from utility_specs.message import Message, Version

T_END = 30.0
FUNCTIONS = {
    "battery": (Battery(depletion_rate=0.05), {"level": st.floats(0.05, 1.0)}),
    "linear": (Linear(), {"initial": st.floats(0.0, 3.0), "slope": st.floats(0.01, 2.0)}),
    "position": (Position(v_max=2.0, area=500.0), {}),
    "poisson": (StatusPoisson(rate=0.2), {}),
    "video": (Video(S=0.1, f_max=5.0, f_1=2.5), {}),
    "red": (RedImage(alpha=10.0, S=0.1, f_max=5.0, f_1=2.5), {"red": st.floats(0.0, 1.0)}),
}


@st.composite
def streams(draw, data_fields, senders=("a", "b", "c")):  # type: ignore[no-untyped-def]
    n = draw(st.integers(0, 12))
    out = []
    for seq in range(n):
        t_gen = draw(st.floats(0.0, T_END, allow_nan=False))
        delay = draw(st.one_of(st.none(), st.floats(0.0, 5.0)))
        data = {k: draw(v) for k, v in data_fields.items()}
        out.append(Message(sender=draw(st.sampled_from(senders)), receiver="g", seq=seq, type="x",
                           t_gen=t_gen, t_rcv=None if delay is None else t_gen + delay, data=data))
    return out


def _total(fn, aggregation, messages, per_sender=True):  # type: ignore[no-untyped-def]
    spec = spec_of(info(fn, aggregation, per_sender=per_sender))
    return evaluate(messages, spec, t_end=T_END).total


@pytest.mark.parametrize("aggregation", ["sum", "max"])
@pytest.mark.parametrize("name", sorted(FUNCTIONS))
@settings(max_examples=40, deadline=None)
@given(data=st.data())
def test_adding_a_received_message_never_lowers_sum_or_max(name, aggregation, data) -> None:  # type: ignore[no-untyped-def]
    fn, fields = FUNCTIONS[name]
    messages = data.draw(streams(fields))
    extra_gen = data.draw(st.floats(0.0, T_END))
    extra = Message(sender=data.draw(st.sampled_from("abc")), receiver="g", seq=99, type="x",
                    t_gen=extra_gen, t_rcv=extra_gen + data.draw(st.floats(0.0, 5.0)),
                    data={k: data.draw(v) for k, v in fields.items()})
    before = _total(fn, aggregation, messages)
    after = _total(fn, aggregation, [*messages, extra])
    assert after >= before - 1e-9 * max(1.0, abs(before))


@pytest.mark.parametrize("aggregation", ["sum", "max", "last"])
@pytest.mark.parametrize("name", sorted(FUNCTIONS))
@settings(max_examples=25, deadline=None)
@given(data=st.data())
def test_totals_do_not_depend_on_log_order(name, aggregation, data) -> None:  # type: ignore[no-untyped-def]
    fn, fields = FUNCTIONS[name]
    messages = data.draw(streams(fields))
    shuffled = data.draw(st.permutations(messages))
    a = _total(fn, aggregation, messages)
    b = _total(fn, aggregation, shuffled)
    assert a == pytest.approx(b, rel=1e-12, abs=1e-12)


@pytest.mark.parametrize("name", sorted(FUNCTIONS))
@settings(max_examples=25, deadline=None)
@given(data=st.data())
def test_per_sender_streams_are_independent(name, data) -> None:  # type: ignore[no-untyped-def]
    fn, fields = FUNCTIONS[name]
    messages = data.draw(streams(fields))
    whole = _total(fn, "max", messages, per_sender=True)
    parts = sum(
        _total(fn, "max", [m for m in messages if m.sender == s], per_sender=True) for s in "abc"
    )
    assert whole == pytest.approx(parts, rel=1e-12, abs=1e-12)
    # changing one sender's stream leaves the others' contributions as they were
    spec = spec_of(info(fn, "max", per_sender=True))
    without_a = [m for m in messages if m.sender != "a"]
    streams_all = evaluate(messages, spec, t_end=T_END).per_stream
    streams_wo = evaluate(without_a, spec, t_end=T_END).per_stream
    for key, value in streams_wo.items():
        assert streams_all[key] == pytest.approx(value, rel=1e-12, abs=1e-12)


GRID = st.integers(0, 40).map(lambda k: k * 0.25)  # coarse times: ties on purpose
VERSIONS = (Version(name="full", size=100, quality=1.0), Version(name="half", size=40,
                                                                   quality=0.5))
COMPARED = {**FUNCTIONS, "status": (Status(), {})}


@st.composite
def versioned_copies(draw, data_fields):  # type: ignore[no-untyped-def]
    """Copies of up to 14 messages on a coarse time grid; some get their full version later."""
    out = []
    for seq in range(draw(st.integers(0, 14))):
        t_gen = draw(GRID)
        data = {k: draw(v) for k, v in data_fields.items()}
        first = Message(sender="a", receiver="g", seq=seq, type="x", t_gen=t_gen,
                        t_rcv=t_gen + draw(GRID) / 4, data=data, versions=VERSIONS,
                        version=draw(st.sampled_from([0, 1])))
        out.append(first)
        if first.version == 1 and draw(st.booleans()):
            assert first.t_rcv is not None
            out.append(replace(first, version=0, t_rcv=first.t_rcv + draw(GRID) / 2))
    return out


@pytest.mark.skipif(not JIT, reason="numba is not installed: no compiled sweep to compare")
@pytest.mark.parametrize("name", sorted(COMPARED))
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_compiled_and_curve_sweeps_agree(name, data) -> None:  # type: ignore[no-untyped-def]
    """The two exact paths of eq. 4.5 on short, tie-rich streams with replaced versions."""
    fn, fields = COMPARED[name]
    copies = data.draw(versioned_copies(fields))
    t_start = data.draw(st.sampled_from([0.0, 2.5, 7.25]))
    occs = [o for _, group in groupby(copies, key=lambda m: m.key) for o in occurrences(group)]
    by_start = sorted(occs, key=lambda o: o.start)
    compiled = _compiled_max(fn, [o.m for o in by_start], [o.start for o in by_start],
                             [o.until for o in by_start], t_start, T_END)
    assert compiled is not None
    for o in occs:
        o.curve = fn.curve(o.m)
    sweep = _max_with_versions(by_start, t_start, T_END)
    assert compiled == pytest.approx(sweep, rel=1e-9, abs=1e-9)
