"""Forecast (ch. 5.1): period with gaps, circular phase, no double counting; latency stats."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.middleware.forecast import LatencyEstimator, StreamForecaster
from tests.middleware.conftest import T0, msg


def test_period_survives_dropped_messages() -> None:
    f = StreamForecaster()
    for k in (0, 1, 2, 5, 6, 9, 13, 14):  # most gaps are multiples of the period
        f.observe(msg("a", k, "battery", T0 + 0.5 * k))
    assert f.period(("a", "battery")) == pytest.approx(0.5, rel=1e-9)


def test_phase_average_wraps_around() -> None:
    """Phases 0.98 and 0.02 of a 1 s period average to ~0.0, not to 0.5."""
    f = StreamForecaster()
    for k, jitter in enumerate([-0.02, 0.02, -0.02, 0.02, -0.02, 0.02]):
        f.observe(msg("a", k, "battery", 100.0 + k + jitter))
    predicted = f.predict(("a", "battery"), t_from=105.1, t_to=106.6)
    assert len(predicted) == 1
    assert predicted[0] == pytest.approx(106.0, abs=0.05)  # a linear mean would say 105.5


def test_known_message_is_never_forecast_again() -> None:
    f = StreamForecaster()
    for k in range(4):
        f.observe(msg("a", k, "battery", T0 + k))
    predicted = f.predict(("a", "battery"), t_from=T0 + 2.5, t_to=T0 + 6.2)
    assert predicted == pytest.approx([T0 + 4, T0 + 5, T0 + 6])
    # the newest known message (T0 + 3) is not predicted even when the range covers it
    assert f.predict(("a", "battery"), t_from=T0 + 2.9, t_to=T0 + 3.1) == []


def test_forecast_carries_last_data_and_mean_size() -> None:
    f = StreamForecaster()
    f.observe(msg("a", 0, "linear", T0, size=100, red=0.1))
    f.observe(msg("a", 1, "linear", T0 + 1, size=300, red=0.7))
    out = f.forecast(("a", "linear"), t_from=T0 + 1, t_to=T0 + 3)
    assert [m.t_gen for m in out] == pytest.approx([T0 + 2, T0 + 3])
    assert all(m.data["red"] == 0.7 and m.size == 200 for m in out)


@settings(max_examples=40, deadline=None)
@given(
    period=st.floats(0.1, 5.0),
    phase=st.floats(0.0, 1.0),
    drop=st.lists(st.booleans(), min_size=12, max_size=12),
)
def test_period_estimate_property(period: float, phase: float, drop: list[bool]) -> None:
    f = StreamForecaster()
    kept = [k for k, d in enumerate(drop) if not d or k in (0, 1)]
    for k in kept:
        f.observe(msg("a", k, "battery", 50.0 + phase * period + k * period))
    assert f.period(("a", "battery")) == pytest.approx(period, rel=1e-6)


def test_latency_is_robust_to_one_outlier() -> None:
    est = LatencyEstimator(default_s=0.05)
    assert est.mean_s == 0.05
    for _ in range(40):
        est.update(0.1)
    est.update(5.0)
    assert est.mean_s < 0.25
    assert est.high_s == pytest.approx(0.1)
    est.update(math.nan)
    assert len(est) == 41


def test_sequence_numbers_tell_a_sparse_fast_stream_from_a_slow_one() -> None:
    """Every third message of a 1 s stream arrives: seq gaps of 3 say the period is 1 s."""
    f = StreamForecaster()
    for k in range(0, 15, 3):
        f.observe(msg("a", k, "battery", T0 + k))
    assert f.period(("a", "battery")) == pytest.approx(1.0)
    g = StreamForecaster()  # the same gaps from a sender with two streams: no seq shortcut
    g.observe(msg("a", 100, "linear", T0))
    for k in range(0, 15, 3):
        g.observe(msg("a", k, "battery", T0 + k))
    assert g.period(("a", "battery")) == pytest.approx(3.0)


def test_seqs_shared_with_unheard_streams_do_not_set_the_period() -> None:
    """A sender numbers all its messages with one counter: 3 Hz images among 1 Hz position
    reports. Only the images are heard of; their seq steps (1 or 2) count the unheard
    positions too, so the period comes from the times (1/3 s), not from seq (about 1/4 s)."""
    f = StreamForecaster()
    events = sorted([(k / 3.0, "image") for k in range(12)] + [(k + 0.1, "position")
                                                             for k in range(4)])
    for seq, (t, kind) in enumerate(events):
        if kind == "image":
            f.observe(msg("a", seq, "image", T0 + t))
    assert f.period(("a", "image")) == pytest.approx(1 / 3.0, rel=1e-6)
    # the other way round the seqs still help: a sender's only stream, every third heard
    h = StreamForecaster()
    for seq in range(0, 30, 3):
        h.observe(msg("b", seq, "image", T0 + seq / 3.0 + 0.01 * (seq % 2)))
    assert h.period(("b", "image")) == pytest.approx(1 / 3.0, rel=0.01)


def test_a_stream_heard_once_repeats_at_the_fleet_period() -> None:
    f = StreamForecaster()
    for k in range(4):
        f.observe(msg("a", k, "battery", T0 + 0.5 * k))
    f.observe(msg("b", 0, "battery", T0 + 1.2))
    f.refresh()
    assert f.predict(("b", "battery"), t_from=T0 + 1.2, t_to=T0 + 2.3) == pytest.approx(
        [T0 + 1.7, T0 + 2.2]
    )
    off = StreamForecaster(assume_fleet_period=False)
    off.observe(msg("b", 0, "battery", T0 + 1.2))
    off.refresh()
    assert off.predict(("b", "battery"), t_from=T0, t_to=T0 + 9) == []


def test_a_stream_heard_once_repeats_at_its_types_declared_period() -> None:
    """Round 15: the mission's first message of a stream, before any period is known: with
    the type's declared ``period_s`` it is forecast at once; without, it is not forecast."""
    f = StreamForecaster(declared={"battery": 1.0})
    f.observe(msg("b", 0, "battery", T0 + 1.2))
    f.observe(msg("c", 0, "status", T0 + 1.2))
    f.refresh()
    assert f.prior_period is None
    assert f.predict(("b", "battery"), t_from=T0 + 1.2, t_to=T0 + 4.0) == pytest.approx(
        [T0 + 2.2, T0 + 3.2])
    assert f.predict(("c", "status"), t_from=T0, t_to=T0 + 9) == []
    for k in range(1, 4):  # heard three times more: its own period wins over the declared one
        f.observe(msg("b", k, "battery", T0 + 1.2 + 0.5 * k))
    f.refresh()
    assert f.predict(("b", "battery"), t_from=T0 + 2.7, t_to=T0 + 4.0) == pytest.approx(
        [T0 + 3.2, T0 + 3.7])


def test_a_stream_that_numbers_its_frames_is_forecast_at_its_generation_rate() -> None:
    """Round 11: a drone sending one of its 3 frames/s every ~1-2 s, among telemetry that
    shares its ``seq`` counter. Its frames carry the camera's frame index (``frame``): the
    steps between heard frames count the periods, so the others forecast all its frames,
    not one per gap heard. Without the index the gaps (3, 4, 6, 5 frames) give no period
    near 1/3 s."""
    frames = [0, 3, 7, 13, 18]
    counted, plain = StreamForecaster(), StreamForecaster()
    for k, n in enumerate(frames):
        t = T0 + n / 3
        counted.observe(msg("d3", 10 * k, "image", t, red=0.5, frame=n))
        plain.observe(msg("d3", 10 * k, "image", t, red=0.5))
        for f in (counted, plain):  # telemetry with the same seq counter
            f.observe(msg("d3", 10 * k + 1, "position", t + 0.05))
    assert counted.period(("d3", "image")) == pytest.approx(1 / 3, rel=1e-9)
    assert plain.period(("d3", "image")) > 0.9
    last = T0 + 18 / 3
    assert len(counted.predict(("d3", "image"), t_from=last, t_to=last + 3.0)) == 9


def test_a_restarted_frame_counter_says_nothing_about_the_period() -> None:
    """The camera's index starts again at 0 after a companion restart: the numbers no
    longer increase, and the period falls back to the gaps."""
    f = StreamForecaster()
    for k, (n, t) in enumerate([(40, 0.0), (43, 1.0), (2, 2.0), (5, 3.0)]):
        f.observe(msg("d3", k, "image", T0 + t, red=0.5, frame=n))
    assert f.period(("d3", "image")) == pytest.approx(1.0, rel=1e-9)
