"""The pacer (companion.protocol.pacer): exact departure times, whole units, the backlog."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.protocol.pacer import Pacer

TO = ("10.0.0.1", 5000)


def _d(size: int) -> bytes:
    """A datagram costing ``size`` bytes on the link (the pacer adds 28 of UDP/IP)."""
    return bytes(size - 28)


def test_a_unit_leaves_at_the_rate_after_the_burst() -> None:
    # 1000 B/s, a bucket of 1000 B: the first datagram at once, then one every 0.5 s
    pacer: Pacer[tuple[str, int]] = Pacer(rate_bytes_per_s=1000.0, burst_bytes=1000)
    unit = [_d(500), _d(500), _d(500), _d(500)]
    assert pacer.offer(unit, TO, now=10.0)
    assert pacer.backlog_bytes == 2000
    assert len(pacer.pop_due(10.0)) == 2  # the full bucket pays for two
    assert pacer.next_due() == 10.5
    assert pacer.idle_at(10.0) == 11.0
    assert pacer.pop_due(10.49) == []
    assert [to for _, to in pacer.pop_due(10.5)] == [TO]
    assert pacer.next_due() == 11.0
    assert len(pacer.pop_due(20.0)) == 1
    assert pacer.next_due() is None and pacer.backlog_bytes == 0
    assert pacer.counters == {"units_queued": 1, "units_dropped": 0,
                              "datagrams_released": 4, "bytes_released": 4 * 472}


def test_release_times_are_exact_and_in_order() -> None:
    pacer: Pacer[str] = Pacer(rate_bytes_per_s=2000.0, burst_bytes=500)
    pacer.offer([_d(500), _d(1000)], "a", now=0.0)
    pacer.offer([_d(250)], "b", now=0.0)
    times = []
    t: float | None = 0.0
    while t is not None:
        times += [(t, to) for _, to in pacer.pop_due(t)]
        t = pacer.next_due()
    # 500 at 0 (bucket full); 1000 > burst: waits for a full bucket (0.25 s), leaves a debt
    # of 500; 250 then waits 0.375 s more
    assert times == [(0.0, "a"), (0.25, "a"), (0.625, "b")]


def test_an_idle_pacer_refills_only_up_to_the_burst() -> None:
    pacer: Pacer[str] = Pacer(rate_bytes_per_s=1000.0, burst_bytes=1000)
    pacer.offer([_d(1000), _d(1000)], "x", now=0.0)
    assert len(pacer.pop_due(0.0)) == 1
    assert len(pacer.pop_due(1.0)) == 1
    pacer.offer([_d(1000)] * 3, "x", now=100.0)  # 99 s idle: still one bucket, not 99
    assert len(pacer.pop_due(100.0)) == 1
    assert pacer.next_due() == 101.0


def test_a_unit_goes_whole_or_not_at_all() -> None:
    pacer: Pacer[str] = Pacer(rate_bytes_per_s=1000.0, burst_bytes=500, max_backlog_bytes=2000)
    assert pacer.offer([_d(500)] * 3, "a", now=0.0)
    assert not pacer.offer([_d(500)] * 2, "b", now=0.0)  # 2500 > 2000: nothing of it queued
    assert pacer.backlog_bytes == 1500 and len(pacer) == 3
    assert pacer.offer([_d(500)], "c", now=0.0)  # a unit that fits still goes
    assert [to for _, to in pacer.pop_due(10.0)] == ["a", "a", "a", "c"]
    assert pacer.counters["units_dropped"] == 1 and pacer.counters["units_queued"] == 2
    assert pacer.max_backlog_seen_bytes == 2000


@pytest.mark.parametrize("rate", [0.0, -1.0, float("nan"), float("inf")])
def test_bad_rates_are_refused(rate: float) -> None:
    with pytest.raises(ValueError, match="rate"):
        Pacer(rate_bytes_per_s=rate)


@settings(max_examples=60, deadline=None)
@given(sizes=st.lists(st.integers(29, 1500), min_size=1, max_size=40),
       gaps=st.lists(st.floats(0.0, 0.2), min_size=1, max_size=40),
       rate=st.floats(500.0, 50_000.0), burst=st.integers(1, 4000))
def test_never_faster_than_rate_plus_one_burst(sizes: list[int], gaps: list[float],
                                               rate: float, burst: int) -> None:
    """Over any interval the pacer releases at most burst + rate·interval bytes (plus one
    datagram: a datagram above the bucket leaves when it is full), and everything leaves."""
    pacer: Pacer[int] = Pacer(rate_bytes_per_s=rate, burst_bytes=burst,
                              max_backlog_bytes=10**9, max_delay_s=math.inf)  # takes all
    released: list[tuple[float, int]] = []
    now = 0.0


    def timer_until(t_end: float) -> None:  # the shell's timer, firing at each due time
        while (due := pacer.next_due()) is not None and due <= t_end:
            released.extend((due, len(d) + 28) for d, _ in pacer.pop_due(due))

    for i, size in enumerate(sizes):
        now += gaps[i % len(gaps)]
        timer_until(now)
        assert pacer.offer([_d(size)], i, now)
        released += [(now, len(d) + 28) for d, _ in pacer.pop_due(now)]
    timer_until(float("inf"))
    assert sum(c for _, c in released) == sum(sizes)
    biggest = max(sizes)
    for i, (t0, _) in enumerate(released):
        window = 0
        for t1, cost in released[i:]:
            window += cost
            assert window <= burst + biggest + rate * (t1 - t0) + 1e-6


def test_a_unit_behind_more_than_max_delay_is_refused_whole() -> None:
    pacer: Pacer[str] = Pacer(rate_bytes_per_s=1000.0, burst_bytes=500, max_delay_s=1.0)
    assert pacer.offer([_d(500)] * 3, "a", now=0.0)  # the last leaves at 1.0 s
    assert pacer.idle_at(0.0) == 1.0
    assert pacer.offer([_d(500)], "b", now=0.0)  # behind exactly 1.0 s: still taken
    assert not pacer.offer([_d(500)], "c", now=0.0)  # behind 1.5 s: refused, nothing queued
    assert len(pacer.pop_due(0.5)) == 2  # the shell's timer: two have left by 0.5 s
    assert pacer.offer([_d(500)], "c", now=0.5)  # now it is behind 1.0 s again
    assert pacer.counters["units_dropped"] == 1 and len(pacer) == 3
