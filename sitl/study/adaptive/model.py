"""The packet-level link model: a FIFO bottleneck with a byte-bounded queue, fed by Poisson
application and background packets (uncoordinated traffic, ch. 6.1), so queueing delay and
hence ‖W‖_Δ grow with load and background as in figures 6.1/6.2. Deliveries come back to the
sender as periodic receiver reports, which is when the constraint learns (not at send).
"""

from __future__ import annotations

import bisect
import heapq
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from companion.middleware.adaptive import LinkStatsConstraint
from companion.middleware.constraint import GoodputConstraint
from companion.middleware.linkstats import WindowStats
from companion.middleware.reports import ReceiverReport, feed_link
from companion.protocol.records import ReportEntry

SIM = "sim"
"""The simulated sender's agent name, and the type of its messages."""

Rate = Callable[[float], float]
"""A rate (bytes per second) as a function of time (s)."""


@dataclass(frozen=True, slots=True)
class Step:
    """A piecewise-constant schedule: ``values[i]`` from ``times[i]`` on."""

    times: tuple[float, ...]
    values: tuple[float, ...]

    def __call__(self, t: float) -> float:
        i = bisect.bisect_right(self.times, t) - 1
        return self.values[max(i, 0)]


def steps(*points: tuple[float, float]) -> Step:
    """``steps((0, a), (40, b))``: a from 0 s, b from 40 s."""
    times, values = zip(*sorted(points), strict=True)
    return Step(tuple(float(t) for t in times), tuple(float(v) for v in values))


@dataclass(frozen=True, slots=True, kw_only=True)
class SimLink:
    """A bottleneck: FIFO queue of at most ``queue_limit_bytes``, then propagation."""

    capacity_bytes_per_s: Rate = field(default_factory=lambda: steps((0.0, 125_000.0)))
    propagation_s: float = 0.02
    queue_limit_bytes: int = 60_000
    report_interval_s: float = 0.2
    message_bytes: int = 1200
    background_packet_bytes: int = 1200


@dataclass(slots=True)
class SimTrace:
    """What happened: one row per processed report, plus every packet."""

    t: list[float] = field(default_factory=list)
    xi_bytes_per_s: list[float] = field(default_factory=list)
    goodput_bytes_per_s: list[float] = field(default_factory=list)
    backlog_bytes_per_s: list[float] = field(default_factory=list)
    latency_s: list[float] = field(default_factory=list)
    background_bytes_per_s: list[float] = field(default_factory=list)
    capacity_bytes_per_s: list[float] = field(default_factory=list)
    demand_bytes_per_s: list[float] = field(default_factory=list)
    sent: list[tuple[float, float | None, int]] = field(default_factory=list)
    """Application packets: (t_sent, t_rcv or None when dropped, size)."""

    def columns(self) -> dict[str, list[float]]:
        return {
            "t_s": self.t,
            "xi_bytes_per_s": self.xi_bytes_per_s,
            "goodput_bytes_per_s": self.goodput_bytes_per_s,
            "backlog_bytes_per_s": self.backlog_bytes_per_s,
            "latency_s": self.latency_s,
            "background_bytes_per_s": self.background_bytes_per_s,
            "capacity_bytes_per_s": self.capacity_bytes_per_s,
            "demand_bytes_per_s": self.demand_bytes_per_s,
        }

    def xi_between(self, t0: float, t1: float) -> np.ndarray:
        t = np.asarray(self.t)
        return np.asarray(self.xi_bytes_per_s)[(t >= t0) & (t < t1)]

    def delivered_rate(self, t0: float, t1: float) -> float:
        """Application bytes per second received in [t0, t1)."""
        total = sum(s for _, r, s in self.sent if r is not None and t0 <= r < t1)
        return total / (t1 - t0)


def _poisson_times(rng: np.random.Generator, rate_hz: Callable[[float], float],
                   max_rate_hz: float, duration_s: float) -> list[float]:
    """A non-homogeneous Poisson process by thinning (Lewis & Shedler 1979)."""
    if max_rate_hz <= 0:
        return []
    n = rng.poisson(max_rate_hz * duration_s * 1.2 + 20)
    times = np.cumsum(rng.exponential(1.0 / max_rate_hz, size=n))
    keep = rng.random(n) * max_rate_hz
    out = [float(t) for t, k in zip(times, keep, strict=True)
           if t < duration_s and k < rate_hz(float(t))]
    return out


def simulate(
    constraint: GoodputConstraint,
    *,
    duration_s: float,
    rng: np.random.Generator,
    link: SimLink | None = None,
    demand_bytes_per_s: Rate | None = None,
    background_bytes_per_s: Rate | None = None,
) -> SimTrace:
    """Run the application over the modelled link.

    The application generates messages as a Poisson process at ``demand_bytes_per_s`` and
    publishes each with probability min(1, ξ/demand), i.e. at rate min(demand, ξ(t)) with
    uncoordinated timing (eq. 6.8 used as a publishing rate). An :class:`ObservedConstant`
    constraint gives the open-loop runs of figures 6.1/6.2.
    """
    link = link or SimLink()
    demand = demand_bytes_per_s or steps((0.0, 10 * 125_000.0))
    background = background_bytes_per_s or steps((0.0, 0.0))
    size = link.message_bytes
    app_times = _poisson_times(
        rng, lambda t: demand(t) / size, _max_of(demand, duration_s) / size, duration_s
    )
    bg_max = _max_of(background, duration_s) / link.background_packet_bytes
    bg_times = _poisson_times(
        rng, lambda t: background(t) / link.background_packet_bytes, bg_max, duration_s
    )
    coin = rng.random(len(app_times))
    # Events: (time, order, kind, index). Reports are written every report_interval_s and
    # reach the sender one propagation delay later.
    events: list[tuple[float, int, str, int]] = []
    for i, t in enumerate(app_times):
        events.append((t, 1, "app", i))
    for i, t in enumerate(bg_times):
        events.append((t, 1, "bg", i))
    n_reports = int(duration_s / link.report_interval_s)
    for k in range(1, n_reports + 1):
        events.append((k * link.report_interval_s + link.propagation_s, 0, "report", k))
    heapq.heapify(events)

    trace = SimTrace()
    busy_until = 0.0
    deliveries: list[tuple[float, int, int]] = []  # heap of (t_rcv, seq, size) app packets
    t_sent_of: dict[int, float] = {}
    seq = 0
    while events:
        t, _, kind, idx = heapq.heappop(events)
        if kind == "report":
            t_written = idx * link.report_interval_s
            entries = []
            while deliveries and deliveries[0][0] <= t_written:
                t_rcv, s, sz = heapq.heappop(deliveries)
                t_sent = t_sent_of.pop(s)
                entries.append(ReportEntry(sender=SIM, type=SIM, seq=s, t_gen=t_sent,
                                           t_sent=t_sent, t_rcv=t_rcv, size=sz))
            feed_link(constraint, ReceiverReport(entries=entries), agent=SIM, now=t)
            xi = constraint.limit_bytes_per_s(now=t)
            stats = getattr(constraint, "last_stats", None)
            trace.t.append(t)
            trace.xi_bytes_per_s.append(xi)
            trace.goodput_bytes_per_s.append(stats.goodput_bytes_per_s if stats else math.nan)
            trace.backlog_bytes_per_s.append(stats.backlog_bytes_per_s if stats else math.nan)
            trace.latency_s.append(stats.mean_latency_s if stats else math.nan)
            trace.background_bytes_per_s.append(background(t))
            trace.capacity_bytes_per_s.append(link.capacity_bytes_per_s(t))
            trace.demand_bytes_per_s.append(demand(t))
            continue
        if kind == "app":
            xi = constraint.limit_bytes_per_s(now=t)
            if coin[idx] * demand(t) >= xi:
                continue  # not published: the app keeps to rate ξ
            constraint.on_sent(size, now=t)
            pkt = size
        else:
            pkt = link.background_packet_bytes
        capacity = link.capacity_bytes_per_s(t)
        backlog = max(0.0, busy_until - t) * capacity
        if backlog + pkt > link.queue_limit_bytes:
            if kind == "app":
                trace.sent.append((t, None, pkt))
            continue  # tail drop
        busy_until = max(t, busy_until) + pkt / capacity
        if kind == "app":
            t_rcv = busy_until + link.propagation_s
            trace.sent.append((t, t_rcv, pkt))
            t_sent_of[seq] = t
            heapq.heappush(deliveries, (t_rcv, seq, pkt))
            seq += 1
    return trace


class ObservedConstant(LinkStatsConstraint):
    """A fixed ξ that still keeps link statistics (for open-loop curves and baselines)."""

    def __init__(self, *, limit_bytes_per_s: float, window_s: float = 2.5) -> None:
        super().__init__(window_s=window_s)
        self._limit = float(limit_bytes_per_s)
        self.observed: list[WindowStats] = []

    def limit_bytes_per_s(self, *, now: float) -> float:
        del now
        return self._limit

    def _learn(self, observations: list[WindowStats]) -> None:
        self.observed.extend(observations)


def _max_of(rate: Rate, duration_s: float) -> float:
    if isinstance(rate, Step):
        return max(rate.values)
    return max(rate(t) for t in np.linspace(0.0, duration_s, 1001))


def mean_backlog_at_rate(
    rate_bytes_per_s: float,
    *,
    background_bytes_per_s: float,
    link: SimLink | None = None,
    duration_s: float = 60.0,
    seed: int = 0,
    window_s: float = 2.5,
) -> float:
    """Mean ‖W‖_Δ over all per-message observations when publishing at a fixed rate.

    One point of a figure 6.2 curve. The mean is per observation because that is what the
    SGD fit of the adaptive constraint averages over.
    """
    observer = ObservedConstant(limit_bytes_per_s=rate_bytes_per_s, window_s=window_s)
    simulate(
        observer,
        duration_s=duration_s,
        rng=np.random.default_rng(seed),
        link=link,
        demand_bytes_per_s=steps((0.0, rate_bytes_per_s)),
        background_bytes_per_s=steps((0.0, background_bytes_per_s)),
    )
    return float(np.mean([o.backlog_bytes_per_s for o in observer.observed]))


def equilibrium_rate(
    alpha_bytes_per_s: float,
    *,
    background_bytes_per_s: float,
    link: SimLink | None = None,
    duration_s: float = 60.0,
    seed: int = 0,
    window_s: float = 2.5,
    iterations: int = 12,
) -> float:
    """The publishing rate r* at which the mean ‖W‖_Δ equals α (eq. 6.6 met with equality).

    Bisection over open-loop runs with common random numbers (same seed), between 0 and what
    the link has left.
    """
    link = link or SimLink()
    lo, hi = 0.0, max(0.0, link.capacity_bytes_per_s(0.0) - background_bytes_per_s)
    for _ in range(iterations):
        mid = (lo + hi) / 2
        backlog = mean_backlog_at_rate(
            mid, background_bytes_per_s=background_bytes_per_s, link=link,
            duration_s=duration_s, seed=seed, window_s=window_s,
        )
        lo, hi = (mid, hi) if backlog < alpha_bytes_per_s else (lo, mid)
    return (lo + hi) / 2
