"""Properties of the model (hypothesis): monotonicity, order invariance, stream independence."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.utility_specs.helpers import info, spec_of
from utility_specs.evaluate import evaluate
from utility_specs.functions import Battery, Linear, Position, RedImage, StatusPoisson, Video
from utility_specs.message import Message

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
