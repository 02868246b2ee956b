"""The drone's own stall is not the link's congestion (docs/companion.md, "Nor is it a
congested link").

A companion that does not run for 4 s (SIGSTOP, swap, an SD card's write) sends, when it
resumes, what its pacer held: stamped before the stop, received 4 s later. Read as latency,
that is 4 s of queueing, and before the fix ξ fell by 70 % for 15 s on an idle link; an image
half sent when it stopped was lost and read as a full queue as well.
"""

from __future__ import annotations

import pytest

from companion.middleware.constraints import make_constraint
from companion.middleware.constraints.base import GoodputConstraint
from companion.middleware.constraints.linkstats import LinkSample, LinkStats
from companion.middleware.constraints.losses import SendLedger
from companion.middleware.reports import ReceiverReport, feed_link
from companion.protocol.records import ReportEntry
from sitl.fleet.link import relay_constraint_params

T0 = 1_700_000_000.0
RATE = 50_000.0
STOP, RESUME = T0 + 10.0, T0 + 14.0


def _report(entries: list[tuple[int, float, float, int]]) -> ReceiverReport:
    return ReceiverReport(entries=[
        ReportEntry(sender="d1", seq=seq, type="x", t_gen=t_sent, t_sent=t_sent, t_rcv=t_rcv,
                    size=size) for seq, t_sent, t_rcv, size in entries])


def _fly(constraint: GoodputConstraint, *, mark: bool) -> float:
    """10 s on an idle link (a 2 kB frame every 0.1 s, 15 ms), two frames stamped just
    before the stop and received at the resume, one half-sent frame lost, then 4 s idle
    again; returns the lowest ξ after the resume."""
    seq, t = 0, T0
    while t < STOP - 0.05:
        constraint.on_sent(2000, now=t)
        feed_link(constraint, _report([(seq, t, t + 0.015, 2000)]), agent="d1", now=t + 0.1)
        seq, t = seq + 1, t + 0.1
    # in the pacer when the process stopped: a frame lost (its fragments split by the stop,
    # the station's reassembly expired) and two that left 4 s late
    for k in range(3):
        constraint.on_sent(2000, now=STOP - 0.05 + 0.01 * k)
    if mark:
        constraint.on_stall(STOP - 1.0, RESUME, now=RESUME)
    feed_link(constraint, _report([(seq + 1, STOP - 0.04, RESUME + 0.01, 2000),
                                   (seq + 2, STOP - 0.03, RESUME + 0.02, 2000)]),
              agent="d1", now=RESUME + 0.1)
    seq, t = seq + 3, RESUME + 0.1
    lowest = constraint.limit_bytes_per_s(now=t)
    while t < RESUME + 4.0:
        constraint.on_sent(2000, now=t)
        feed_link(constraint, _report([(seq, t, t + 0.015, 2000)]), agent="d1", now=t + 0.1)
        seq, t = seq + 1, t + 0.1
        lowest = min(lowest, constraint.limit_bytes_per_s(now=t))
    return lowest


@pytest.mark.parametrize("name", ["adaptive", "aimd"])
def test_what_a_stall_delayed_or_lost_does_not_cut_the_constraint(name: str) -> None:
    params = relay_constraint_params(name, RATE)
    told = make_constraint(name, **params)
    untold = make_constraint(name, **params)
    before = make_constraint(name, **params)
    xi_told, xi_untold = _fly(told, mark=True), _fly(untold, mark=False)
    # the same flight without the stall's three frames: what the link alone says
    xi_clean = _fly_clean(before)
    assert xi_told == pytest.approx(xi_clean, rel=0.05)
    if name == "adaptive":  # the product's default: the failure this guards against
        assert xi_untold < 0.8 * xi_clean
    assert told.stats.counters["stalled"] == 2  # type: ignore[attr-defined]


def _fly_clean(constraint: GoodputConstraint) -> float:
    seq, t, lowest = 0, T0, float("inf")
    while t < RESUME + 4.0:
        if not STOP - 0.05 <= t < RESUME + 0.1:
            constraint.on_sent(2000, now=t)
            feed_link(constraint, _report([(seq, t, t + 0.015, 2000)]), agent="d1",
                      now=t + 0.1)
        seq, t = seq + 1, t + 0.1
        if t >= RESUME + 0.1:
            lowest = min(lowest, constraint.limit_bytes_per_s(now=t))
    return lowest


def test_link_stats_skip_own_messages_sent_in_a_stall_only() -> None:
    stats = LinkStats(window_s=2.5).mark_stall(T0 + 1.0, T0 + 5.0)
    stats.update(LinkSample(t_sent=T0 + 0.5, t_rcv=T0 + 0.52, size=100, sender="d1", seq=1),
                 now=T0 + 1)
    stats.update(LinkSample(t_sent=T0 + 1.5, t_rcv=T0 + 5.01, size=100, sender="d1", seq=2),
                 now=T0 + 6)
    stats.update(LinkSample(t_sent=T0 + 5.5, t_rcv=T0 + 5.52, size=100, sender="d1", seq=3),
                 now=T0 + 6)
    assert stats.counters["samples"] == 2 and stats.counters["stalled"] == 1
    window = stats.get()
    assert window is not None and window.mean_latency_s == pytest.approx(0.02)
    assert LinkStats(window_s=2.5).mark_stall(T0 + 5, T0 + 1)._stalls == type(
        stats._stalls)(maxlen=8)  # an interval backwards is no interval


def test_the_ledger_forgets_the_sends_of_a_stall() -> None:
    ledger = SendLedger()
    for i, size in enumerate([200, 7000, 7500, 200]):
        ledger.on_sent(size, now=float(i))
    ledger.forget(0.5, 2.5)  # the two frames went out while the agent stalled
    assert ledger.on_delivered(200) == 0 and ledger.on_delivered(200) == 0
    assert ledger.counters["lost"] == 0 and len(ledger) == 0
