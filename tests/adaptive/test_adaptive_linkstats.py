"""Link statistics (eq. 6.2, 6.4, 6.5) and the NTP-style clock offset, against references."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.middleware.constraint import LinkSample
from companion.middleware.linkstats import (
    ClockOffsetEstimator,
    LinkStats,
    RoundTrip,
)

T0 = 1_700_000_000.0


def sample(t_sent: float, t_rcv: float, size: int = 1000, seq: int = -1) -> LinkSample:
    return LinkSample(t_sent=T0 + t_sent, t_rcv=T0 + t_rcv, size=size, sender="d1", seq=seq)


def test_window_values_match_the_equations_exactly() -> None:
    stats = LinkStats(window_s=2.0, base_window_s=10.0, min_base_latency_s=1e-6)
    # latencies 0.010, 0.030, 0.020 s; sizes 1000, 2000, 3000 B
    for i, (t_sent, latency, size) in enumerate([(0.0, 0.010, 1000), (0.5, 0.030, 2000),
                                                (1.0, 0.020, 3000)]):
        stats.update(sample(t_sent, t_sent + latency, size, seq=i), now=T0 + t_sent + 0.1)
    got = stats.get()
    assert got is not None
    assert got.n_messages == 3
    assert got.goodput_bytes_per_s == pytest.approx(6000 / 2.0)  # eq. 6.2
    assert got.mean_latency_s == pytest.approx(0.020)  # eq. 6.5
    assert got.base_latency_s == pytest.approx(0.010)
    # eq. 6.4: G·L/δ̂ − G = 3000·0.020/0.010 − 3000 = 3000
    assert got.backlog_bytes_per_s == pytest.approx(3000.0)
    assert got.queueing_delay_s == pytest.approx(0.010)
    assert got.warm is False  # only 1.0 s of observations for a 2.0 s window


def test_window_slides_on_reception_time_and_becomes_warm() -> None:
    stats = LinkStats(window_s=1.0, base_window_s=5.0)
    for i in range(30):  # one 1000 B message every 0.1 s, latency 50 ms
        t = i * 0.1
        stats.update(sample(t, t + 0.05, seq=i), now=T0 + t + 0.2)
    got = stats.get()
    assert got is not None and got.warm
    assert got.n_messages == 10  # (t_end − 1.0, t_end]: 10 arrivals
    assert got.goodput_bytes_per_s == pytest.approx(10_000.0)
    assert got.t_end == pytest.approx(T0 + 2.95)


def test_base_latency_forgets_after_its_window_like_bbr() -> None:
    """A route change to a longer path must not leave δ̂ frozen at the old minimum."""
    stats = LinkStats(window_s=1.0, base_window_s=4.0)
    t = 0.0
    while t < 3.0:
        stats.update(sample(t, t + 0.010), now=T0 + t)
        t += 0.1
    assert stats.get().base_latency_s == pytest.approx(0.010)  # type: ignore[union-attr]
    while t < 6.0:  # new route: 40 ms
        stats.update(sample(t, t + 0.040), now=T0 + t)
        t += 0.1
    assert stats.get().base_latency_s == pytest.approx(0.010)  # type: ignore[union-attr]
    while t < 8.0:
        stats.update(sample(t, t + 0.040), now=T0 + t)
        t += 0.1
    # 4 s after the last 10 ms sample the minimum is the new path's
    assert stats.get().base_latency_s == pytest.approx(0.040)  # type: ignore[union-attr]


def test_duplicates_stale_and_invalid_samples_are_counted_not_learned() -> None:
    stats = LinkStats(window_s=1.0)
    stats.update(sample(0.0, 0.01, seq=1), now=T0)
    stats.update(sample(0.0, 0.01, seq=1), now=T0)  # same report twice
    stats.update(sample(5.0, 5.01, seq=2), now=T0)
    stats.update(sample(0.5, 0.51, seq=3), now=T0)  # older than the window
    stats.update(LinkSample(t_sent=math.nan, t_rcv=T0, size=10, seq=4), now=T0)
    assert stats.counters == {"samples": 2, "duplicate": 1, "stale": 1, "invalid": 1,
                              "stalled": 0}
    assert stats.get().n_messages == 1  # type: ignore[union-attr]


def test_no_sample_no_statistics() -> None:
    assert LinkStats().get() is None
    assert ClockOffsetEstimator().get() is None


def test_round_trip_offset_and_delay_are_the_ntp_formulas() -> None:
    # local clock = true time; remote clock = true + 3.0; uplink 0.05 s, downlink 0.01 s,
    # receiver holds the report 0.2 s.
    rt = RoundTrip(t_sent=T0, t_remote_rcv=T0 + 3.05, t_remote_sent=T0 + 3.25, t_rcv=T0 + 0.26)
    assert rt.delay_s == pytest.approx(0.06)
    assert rt.offset_s == pytest.approx(3.0 + (0.05 - 0.01) / 2)
    # the true offset is within the uncertainty bound delay/2
    assert abs(rt.offset_s - 3.0) <= rt.delay_s / 2 + 1e-12


def test_round_trip_rejects_impossible_times() -> None:
    with pytest.raises(ValueError, match="before t_sent"):
        RoundTrip(t_sent=T0, t_remote_rcv=T0, t_remote_sent=T0, t_rcv=T0 - 1)
    with pytest.raises(ValueError, match="finite"):
        RoundTrip(t_sent=math.inf, t_remote_rcv=T0, t_remote_sent=T0, t_rcv=T0)


def test_offset_estimator_uses_the_lowest_delay_round_trip_of_its_history() -> None:
    est = ClockOffsetEstimator(history_s=10.0)
    skew = 3.0
    # (local send time, uplink delay, downlink delay): the 2nd has the smallest total delay
    for t, up, down in [(0.0, 0.30, 0.01), (1.0, 0.02, 0.01), (2.0, 0.50, 0.02)]:
        est.update(RoundTrip(t_sent=T0 + t, t_remote_rcv=T0 + t + up + skew,
                             t_remote_sent=T0 + t + up + skew + 0.1,
                             t_rcv=T0 + t + up + 0.1 + down))
    got = est.get()
    assert got is not None
    assert got.offset_s == pytest.approx(skew + (0.02 - 0.01) / 2)
    assert got.uncertainty_s == pytest.approx(0.015)
    assert got.n_samples == 3
    # 10 s later the good sample has left the history: uplink 0.2 s, downlink 0 s now,
    # so the best remaining round trip has delay 0.2 s and a biased offset skew + 0.1 s
    est.update(RoundTrip(t_sent=T0 + 12.0, t_remote_rcv=T0 + 12.2 + skew,
                         t_remote_sent=T0 + 12.3 + skew, t_rcv=T0 + 12.3))
    got = est.get()
    assert got is not None
    assert got.n_samples == 2
    assert got.uncertainty_s == pytest.approx(0.1, abs=1e-6)
    assert got.offset_s == pytest.approx(skew + 0.1, abs=1e-6)
    assert abs(got.offset_s - skew) <= got.uncertainty_s + 1e-6


def test_latencies_are_corrected_by_the_estimated_offset() -> None:
    """A receiver clock 3 s ahead: raw latencies are ~3 s; corrected ones are the truth."""
    skew = 3.0
    stats = LinkStats(window_s=1.0, min_base_latency_s=1e-6)
    for i in range(20):
        t = i * 0.1
        latency = 0.02 + 0.01 * (i % 2)
        stats.update(sample(t, t + latency + skew, seq=i), now=T0 + t)
    before = stats.get()
    assert before is not None and before.mean_latency_s == pytest.approx(skew + 0.025, abs=1e-3)
    stats.on_round_trip(RoundTrip(t_sent=T0 + 1.9, t_remote_rcv=T0 + 1.92 + skew,
                                  t_remote_sent=T0 + 1.95 + skew, t_rcv=T0 + 1.97))
    after = stats.get()
    assert after is not None
    assert after.mean_latency_s == pytest.approx(0.025, abs=1e-3)
    assert after.base_latency_s == pytest.approx(0.020, abs=1e-3)
    # the queueing delay L − δ̂ does not depend on the clock offset at all
    assert after.queueing_delay_s == pytest.approx(before.queueing_delay_s)


def _reference(samples: list[tuple[float, float, int, int]], window_s: float,
               base_window_s: float) -> tuple[int, float, float, float]:
    """Brute force over all accepted samples: (n, G, L, δ̂) of the current window."""
    accepted: list[tuple[float, float, int, int]] = []
    newest = -math.inf
    for t_sent, t_rcv, size, seq in samples:
        if t_rcv <= newest - window_s:
            continue  # stale
        newest = max(newest, t_rcv)  # a newer reception moves the window, even a repeat
        if seq in {s for _, tr, _, s in accepted if tr > newest - window_s}:
            continue  # duplicate of a message still in the window
        accepted.append((t_sent, t_rcv, size, seq))
    win = [a for a in accepted if a[1] > newest - window_s]
    base = min(tr - ts for ts, tr, _, _ in accepted if tr > newest - base_window_s)
    goodput = sum(a[2] for a in win) / window_s
    latency = sum(a[1] - a[0] for a in win) / len(win)
    return len(win), goodput, latency, base


@settings(max_examples=40, deadline=None)
@given(
    st.lists(
        st.tuples(st.floats(0.0, 0.3), st.floats(0.001, 0.5), st.integers(1, 1500),
                  st.integers(0, 40)),
        min_size=1, max_size=40,
    )
)
def test_incremental_statistics_equal_a_batch_reference(
    steps: list[tuple[float, float, int, int]],
) -> None:
    """At every prefix, O(1) incremental sums equal a brute-force recomputation."""
    stats = LinkStats(window_s=1.0, base_window_s=2.0, min_base_latency_s=1e-6)
    fed: list[tuple[float, float, int, int]] = []
    t = 0.0
    for gap, latency, size, seq in steps:
        t += gap
        fed.append((T0 + t - latency, T0 + t, size, seq))
        stats.update(LinkSample(t_sent=T0 + t - latency, t_rcv=T0 + t, size=size, seq=seq),
                     now=T0 + t)
        n, goodput, mean_latency, base = _reference(fed, 1.0, 2.0)
        got = stats.get()
        assert got is not None
        assert got.n_messages == n
        assert math.isclose(got.goodput_bytes_per_s, goodput, rel_tol=1e-9)
        assert math.isclose(got.mean_latency_s, mean_latency, rel_tol=1e-7, abs_tol=1e-9)
        assert math.isclose(got.base_latency_s, base, abs_tol=1e-9)
        expected = goodput * (mean_latency - base) / base
        assert math.isclose(got.backlog_bytes_per_s, expected, rel_tol=1e-6, abs_tol=1e-6)


def test_bad_parameters_are_rejected_with_their_name() -> None:
    with pytest.raises(ValueError, match="window_s"):
        LinkStats(window_s=0)
    with pytest.raises(ValueError, match="base_window_s"):
        LinkStats(window_s=2.0, base_window_s=1.0)
    with pytest.raises(ValueError, match="history_s"):
        ClockOffsetEstimator(history_s=-1)
