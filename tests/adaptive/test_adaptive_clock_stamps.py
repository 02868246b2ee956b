"""A round trip with impossible stamps must not become the clock-offset estimate.

On the loaded real link (2026-11-24, quick run) the probe sender stamped a report's arrival
before draining its socket; one round trip then came out shorter than the receiver's hold
time. Its delay was clamped to 0, the best possible, and its offset, 55.7 ms off, became the
estimate (uncertainty "0.0 ms") for the next 60 s.
"""

from __future__ import annotations

import pytest

from companion.middleware.linkstats import ClockOffsetEstimator, RoundTrip


def test_a_round_trip_shorter_than_the_hold_time_is_ignored() -> None:
    est = ClockOffsetEstimator()
    # a good round trip: 4 ms there and back, clocks equal, held 50 ms at the receiver
    est.update(RoundTrip(t_sent=10.000, t_remote_rcv=10.002, t_remote_sent=10.052,
                         t_rcv=10.054))
    # t4 stamped 112 ms early: (t4 − t1) = 0.002 s < hold 0.100 s
    bad = RoundTrip(t_sent=11.000, t_remote_rcv=11.002, t_remote_sent=11.102, t_rcv=11.002)
    assert bad.delay_s == 0.0  # the clamped delay that made it win before
    est.update(bad)
    got = est.get()
    assert got is not None
    assert got.offset_s == pytest.approx(0.0, abs=1e-12)
    assert got.uncertainty_s == pytest.approx(0.002)
    assert est.rejected == 1


def test_round_trips_with_a_zero_delay_are_still_used() -> None:
    """The boundary: a round trip exactly as long as the hold time is possible (loopback)."""
    est = ClockOffsetEstimator()
    est.update(RoundTrip(t_sent=1.0, t_remote_rcv=1.5, t_remote_sent=1.6, t_rcv=1.1))
    got = est.get()
    assert got is not None and got.offset_s == pytest.approx(0.5) and est.rejected == 0
