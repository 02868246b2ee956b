"""The constraint's inputs on a narrow shared link (docs/adaptive.md, "The demo's narrow
link"): the fleet's goodput, and a message's transmission time kept apart from queueing."""

from __future__ import annotations

import math

import pytest

from companion.middleware.constraints import make_constraint
from companion.middleware.constraints.adaptive import AdaptiveConstraint
from companion.middleware.constraints.linkstats import LinkSample, LinkStats
from companion.middleware.constraints.losses import SendLedger
from companion.middleware.errors import LinkStatsError
from companion.middleware.reports import ReceiverReport, feed_link, link_observations
from companion.protocol.records import ReportEntry
from sitl.fleet.link import relay_constraint_params

T0 = 1_700_000_000.0
"""A fleet clock in seconds: latencies are exact to ~1e-6 s here (backlogs to 1 B/s)."""
RATE = 50_000.0  # the demo relay's 400 kbit/s


def own(t_sent: float, latency: float, size: int, seq: int) -> LinkSample:
    return LinkSample(t_sent=T0 + t_sent, t_rcv=T0 + t_sent + latency, size=size,
                      sender="d1", seq=seq)


def other(t_sent: float, latency: float, size: int, seq: int, sender: str = "d2"
          ) -> LinkSample:
    return LinkSample(t_sent=T0 + t_sent, t_rcv=T0 + t_sent + latency, size=size,
                      sender=sender, seq=seq, own=False)


def test_other_agents_messages_count_in_the_fleet_goodput_only() -> None:
    stats = LinkStats(window_s=1.0, fleet_goodput=True, min_base_latency_s=0.01)
    stats.update(own(0.0, 0.002, 200, 0), now=T0)
    # another drone's frame: 6000 B received at 0.1 s, sent by a clock 5 s behind: its
    # "latency" must not count
    stats.update(other(-4.9, 5.0, 6000, 0), now=T0)
    stats.update(own(0.3, 0.004, 200, 1), now=T0)
    got = stats.get()
    assert got is not None
    assert got.goodput_bytes_per_s == pytest.approx(6400.0)
    assert got.n_messages == 3
    assert got.mean_latency_s == pytest.approx(0.003, abs=1e-6)  # own messages only
    assert got.base_latency_s == pytest.approx(0.002, abs=1e-6)
    assert stats.counters["samples"] == 2 and stats.others == 1
    # a repeated report entry of the other drone is a duplicate, not more goodput
    stats.update(other(-4.9, 5.0, 6000, 0), now=T0)
    assert stats.counters["duplicate"] == 1
    assert stats.get().goodput_bytes_per_s == pytest.approx(6400.0)  # type: ignore[union-attr]


def test_without_fleet_goodput_other_agents_messages_are_ignored() -> None:
    stats = LinkStats(window_s=1.0)
    stats.update(other(0.0, 0.002, 6000, 0), now=T0)
    assert stats.get() is None and stats.others == 1
    assert stats.counters == {"samples": 0, "duplicate": 0, "stale": 0, "invalid": 0,
                              "stalled": 0}
    stats.update(own(0.1, 0.002, 200, 0), now=T0)
    assert stats.get().goodput_bytes_per_s == pytest.approx(200.0)  # type: ignore[union-attr]


def test_another_agents_message_alone_gives_no_window() -> None:
    """No own message in the window: no latency to read, so no statistics (not Δ = 0)."""
    stats = LinkStats(window_s=1.0, fleet_goodput=True)
    stats.update(other(0.0, 0.002, 6000, 0), now=T0)
    assert stats.get() is None


def test_a_frames_transmission_time_is_not_queueing() -> None:
    """The demo's case: telemetry at 0.3 ms, a 6 kB frame at 6000/50000 s + 0.3 ms on an
    empty link. Without the rate the frame reads as 120 ms of queueing, Δ ≈ 3.9·G."""
    samples = [own(0.0, 0.0003, 200, 0), own(0.2, 0.0003 + 6000 / RATE, 6000, 1),
               own(0.5, 0.0003, 200, 2)]
    thesis = LinkStats(window_s=1.0, min_base_latency_s=0.01)
    rated = LinkStats(window_s=1.0, min_base_latency_s=0.01, link_rate_bytes_per_s=RATE)
    for s in samples:
        thesis.update(s, now=T0)
        rated.update(s, now=T0)
    t, r = thesis.get(), rated.get()
    assert t is not None and r is not None
    assert t.queueing_delay_s == pytest.approx(0.04, abs=1e-6)  # (0 + 0.12 + 0) / 3
    assert t.backlog_bytes_per_s == pytest.approx(6400 * 0.04 / 0.01, abs=1.0)
    assert r.queueing_delay_s == pytest.approx(0.0, abs=1e-6)
    assert r.backlog_bytes_per_s == pytest.approx(0.0, abs=1.0)
    assert r.mean_latency_s == pytest.approx(t.mean_latency_s, abs=1e-6)  # ‖W‖_L is unchanged


def test_queueing_behind_a_frame_is_still_seen_against_the_empty_link_latency() -> None:
    """Telemetry that waited 60 ms behind a frame, and a frame that waited 120 ms: each
    message's queueing counts, and eq. 6.4's divisor is the window's latency on an empty
    link, δ̂ + mean(size/rate), floored."""
    stats = LinkStats(window_s=1.0, min_base_latency_s=0.01, link_rate_bytes_per_s=RATE)
    for s in [own(0.0, 0.001, 250, 0), own(0.1, 0.001 + 0.12 + 6000 / RATE, 6000, 1),
              own(0.2, 0.061 + 250 / RATE, 250, 2), own(0.3, 0.0005, 500, 3)]:
        stats.update(s, now=T0)
    got = stats.get()
    assert got is not None
    base = 0.0005
    # per message: max(0, latency − δ̂ − size/rate)
    queueing = [max(0.0, 0.001 - base - 250 / RATE), 0.12 + 0.001 - base,
                0.061 - base, 0.0]
    assert got.queueing_delay_s == pytest.approx(sum(queueing) / 4, abs=1e-6)
    divisor = base + (250 + 6000 + 250 + 500) / RATE / 4
    assert got.backlog_bytes_per_s == pytest.approx(7000 * (sum(queueing) / 4) / divisor,
                                                    abs=1.0)
    # telemetry alone: the divisor is the floor, as in the thesis' reading
    alone = LinkStats(window_s=1.0, min_base_latency_s=0.01, link_rate_bytes_per_s=RATE)
    alone.update(own(0.0, 0.0005, 100, 0), now=T0)
    alone.update(own(0.1, 0.0205 + 100 / RATE, 100, 1), now=T0)
    one = alone.get()
    assert one is not None
    assert one.backlog_bytes_per_s == pytest.approx(200 * 0.01 / 0.01, abs=1.0)


def test_bad_link_rate_is_refused() -> None:
    for bad in (-1.0, float("inf"), float("nan")):
        with pytest.raises(LinkStatsError, match="link_rate_bytes_per_s"):
            LinkStats(link_rate_bytes_per_s=bad)


def _entries(sender: str, seq0: int, t: float) -> list[ReportEntry]:
    return [ReportEntry(sender=sender, seq=seq0 + k, type="status", t_gen=t + 0.1 * k,
                        t_sent=t + 0.1 * k, t_rcv=t + 0.1 * k + 0.001, size=1000)
            for k in range(5)]


def test_feed_link_hands_other_agents_entries_only_to_a_fleet_goodput_constraint() -> None:
    report = ReceiverReport(entries=[*_entries("d1", 0, T0), *_entries("d2", 0, T0)])
    fleet = AdaptiveConstraint(window_s=1.0, fleet_goodput=True)
    fed = feed_link(fleet, report, agent="d1", now=T0 + 1)
    assert (fed.link_samples, fed.other_samples) == (5, 5)
    assert fleet.stats.counters["samples"] == 5 and fleet.stats.others == 5
    got = fleet.stats.get()
    assert got is not None and got.goodput_bytes_per_s == pytest.approx(10_000.0)
    alone = AdaptiveConstraint(window_s=1.0)
    fed = feed_link(alone, report, agent="d1", now=T0 + 1)
    assert (fed.link_samples, fed.other_samples) == (5, 0)
    got = alone.stats.get()
    assert got is not None and got.goodput_bytes_per_s == pytest.approx(5000.0)


def test_other_agents_messages_add_no_sgd_steps() -> None:
    """One model update per own message, as before: the others' entries only change G."""
    fleet = AdaptiveConstraint(window_s=0.5, fleet_goodput=True)
    alone = AdaptiveConstraint(window_s=0.5)
    entries = [e for k in range(4) for e in (*_entries("d1", 5 * k, T0 + 0.5 * k),
                                             *_entries("d2", 5 * k, T0 + 0.5 * k))]
    feed_link(fleet, ReceiverReport(entries=entries), agent="d1", now=T0 + 3)
    feed_link(alone, ReceiverReport(entries=entries), agent="d1", now=T0 + 3)
    assert fleet.n_updates == alone.n_updates > 0


def test_the_relay_fleet_learns_the_fleets_goodput_at_the_relays_rate_and_its_losses() -> None:
    constraint = make_constraint("adaptive", **relay_constraint_params("adaptive", RATE))
    assert constraint.fleet_goodput is True  # type: ignore[attr-defined]
    assert constraint.stats.link_rate_bytes_per_s == RATE  # type: ignore[attr-defined]
    assert constraint.loss_is_congestion is True  # type: ignore[attr-defined]
    thesis = make_constraint("adaptive")
    assert thesis.fleet_goodput is False  # type: ignore[attr-defined]
    assert thesis.loss_is_congestion is False  # type: ignore[attr-defined]


def test_the_ledger_finds_the_messages_a_fifo_link_lost() -> None:
    ledger = SendLedger()
    for i, size in enumerate([200, 7000, 7500, 200, 300]):
        ledger.on_sent(size, now=float(i))
    assert ledger.on_delivered(200) == 0
    # the 7000 and 7500 B frames never arrived: the next status shows both lost
    assert ledger.on_delivered(200) == 2
    assert ledger.on_delivered(999) == 0  # never sent as far as the ledger knows: no loss
    assert ledger.on_delivered(300) == 0
    assert ledger.counters == {"sent": 5, "delivered": 3, "lost": 2, "unmatched": 1}
    assert len(ledger) == 0


def test_the_ledger_forgets_old_sends_without_counting_them_lost() -> None:
    ledger = SendLedger(max_records=3, horizon=2)
    for i in range(5):
        ledger.on_sent(100 + i, now=float(i))
    assert len(ledger) == 3
    assert ledger.on_delivered(104) == 0  # beyond the horizon of 2: not matched
    assert ledger.on_delivered(103) == 1
    assert ledger.counters["lost"] == 1


def _fleet_report(sizes: list[int], seqs: list[int], t: float) -> ReceiverReport:
    return ReceiverReport(entries=[
        ReportEntry(sender="d1", seq=seq, type="x", t_gen=t + 0.01 * k, t_sent=t + 0.01 * k,
                    t_rcv=t + 0.01 * k + 0.001, size=size)
        for k, (size, seq) in enumerate(zip(sizes, seqs, strict=True))])


@pytest.mark.parametrize("name", ["adaptive", "aimd"])
def test_a_lost_message_makes_its_reports_windows_congested(name: str) -> None:
    """Same sends and reports, latency never rising: only the constraint that reads loss
    as congestion lowers ξ when a frame is missing from the reports."""
    params = relay_constraint_params(name, RATE)
    lossy = make_constraint(name, **params)
    blind = make_constraint(name, **{**params, "loss_is_congestion": False})
    t, seq = T0, 0
    for step in range(12):  # 3 s: one status and one frame every 0.25 s, all delivered
        for c in (lossy, blind):
            c.on_sent(200, now=t)
            c.on_sent(6000, now=t + 0.01)
            c.on_samples(link_observations(_fleet_report([200, 6000], [seq, seq + 1], t),
                                           agent="d1")[0], now=t + 0.2)
        t, seq = t + 0.25, seq + 2
        if step == 9:
            xi_lossy, xi_blind = (c.limit_bytes_per_s(now=t) for c in (lossy, blind))
            assert xi_lossy == pytest.approx(xi_blind)
    for c in (lossy, blind):  # a frame lost, then a status delivered
        c.on_sent(6000, now=t)
        c.on_sent(200, now=t + 0.01)
        c.on_samples(link_observations(_fleet_report([200], [seq + 1], t), agent="d1")[0],
                     now=t + 0.2)
    assert lossy.last_stats is not None and lossy.last_stats.lost == 1  # type: ignore[attr-defined]
    assert lossy.last_stats.backlog_bytes_per_s == math.inf  # type: ignore[attr-defined]
    assert blind.last_stats is not None and blind.last_stats.lost == 0  # type: ignore[attr-defined]
    # AIMD: one multiplicative step (b = 0.998) where the blind one increased
    cut = 0.99 if name == "adaptive" else 1.0
    assert lossy.limit_bytes_per_s(now=t) < cut * blind.limit_bytes_per_s(now=t)
    assert lossy.ledger.counters["lost"] == 1  # type: ignore[attr-defined]
