"""Study: the adaptive goodput constraint against AIMD (thesis figure 6.5) and RFC 8867 5.1.

``uav-sitl study adaptive-vs-aimd --out DIR`` runs, on a seeded packet-level model of a
bottleneck link, (a) the figure 6.5 scenario (on/off application demand, background traffic
stepping up half-way) with the adaptive constraint and with AIMD, and (b) the capacity
schedule of RFC 8867 test 5.1 (1 -> 2.5 -> 0.6 -> 1 x capacity at 0/40/60/80 s) with adaptive,
AIMD and a fixed constraint; it writes one CSV per run and PNG panels (constraint,
application goodput, background / capacity). With ``--real`` (root, iproute2, iperf3) it also
runs the RFC schedule on a real kernel link between network namespaces (see
:mod:`sitl.linkexp`-style runner :func:`sitl.linkemu.run_link_experiment`).

The link model (:func:`simulate`) is a FIFO bottleneck with a byte-bounded queue, fed by
Poisson application and background packets (uncoordinated traffic, ch. 6.1): queueing delay
and hence ‖W‖_Δ grow with load and background as in figures 6.1/6.2. Deliveries come back to
the sender as periodic receiver reports, which is when the constraint learns (not at send).
"""

from __future__ import annotations

import argparse
import bisect
import csv
import heapq
import itertools
import math
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from companion.middleware.adaptive import LinkStatsConstraint
from companion.middleware.constraint import GoodputConstraint, LinkSample
from companion.middleware.constraints import make_constraint
from companion.middleware.linkstats import WindowStats

__all__ = [
    "ObservedConstant",
    "SimLink",
    "SimTrace",
    "Step",
    "equilibrium_rate",
    "main",
    "mean_backlog_at_rate",
    "simulate",
    "steps",
]

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
            samples = []
            while deliveries and deliveries[0][0] <= t_written:
                t_rcv, s, sz = heapq.heappop(deliveries)
                samples.append(LinkSample(t_sent=t_sent_of.pop(s), t_rcv=t_rcv, size=sz,
                                          sender="sim", seq=s))
            _feed(constraint, samples, now=t)
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


def _feed(constraint: GoodputConstraint, samples: Sequence[LinkSample], *, now: float) -> None:
    batch = getattr(constraint, "on_samples", None)
    if batch is not None:
        batch(samples, now=now)
    else:
        for sample in samples:
            constraint.on_sample(sample, now=now)


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


# --------------------------------------------------------------------------------------------
# Real kernel link (network namespaces + tc tbf + iperf3), used by the benchmark and the
# netns integration test.

MESSAGE_BYTES = 1200


@dataclass(frozen=True, slots=True, kw_only=True)
class LinkScenario:
    """A run on a real shaped link: rate steps, background steps, duration."""

    name: str
    duration_s: float
    rate_bit_per_s: tuple[tuple[float, float], ...]
    """(t from start, tbf rate) steps; the first must be at t = 0."""
    background_bit_per_s: tuple[tuple[float, float], ...] = ((0.0, 0.0),)
    """(t from start, iperf3 UDP payload rate) steps; 0 switches it off."""
    queue_limit_bytes: int = 37_500
    receiver_clock_offset_s: float = 0.0
    """Skew of the receiver's clock, to exercise the clock-offset estimate."""

    @property
    def step_times(self) -> list[float]:
        times = {t for t, _ in self.rate_bit_per_s} | {t for t, _ in self.background_bit_per_s}
        return sorted(t for t in times if t < self.duration_s)

    def left_bytes_per_s(self, t: float, payload_bytes: int = MESSAGE_BYTES) -> float:
        """UDP payload bytes per second the link has left for the application at ``t``."""
        rate = steps(*self.rate_bit_per_s)(t)
        capacity = rate / 8 * payload_bytes / (payload_bytes + 42)
        return max(0.0, capacity - steps(*self.background_bit_per_s)(t) / 8)


def rfc8867_5_1(*, base_bit_per_s: float = 1_000_000.0, time_scale: float = 1.0) -> LinkScenario:
    """RFC 8867 test 5.1 (variable available capacity, one flow): 1, 2.5, 0.6, 1 x base.

    Steps at 0/40/60/80 s of a 100 s run; ``time_scale`` < 1 compresses it.
    """
    k = time_scale
    return LinkScenario(
        name="rfc8867-5.1" + ("" if k == 1 else f"-x{k:g}"),
        duration_s=100 * k,
        rate_bit_per_s=((0.0, base_bit_per_s), (40 * k, 2.5 * base_bit_per_s),
                        (60 * k, 0.6 * base_bit_per_s), (80 * k, base_bit_per_s)),
    )


def background_step(*, base_bit_per_s: float = 1_000_000.0, background_share: float = 0.4,
                    t_on_s: float = 20.0, duration_s: float = 40.0,
                    receiver_clock_offset_s: float = 0.0) -> LinkScenario:
    """Thesis figure 7.4 in small: iperf3 UDP background switched on mid-run."""
    return LinkScenario(
        name="background-step",
        duration_s=duration_s,
        rate_bit_per_s=((0.0, base_bit_per_s),),
        background_bit_per_s=((0.0, 0.0), (t_on_s, background_share * base_bit_per_s)),
        receiver_clock_offset_s=receiver_clock_offset_s,
    )


@dataclass(slots=True, kw_only=True)
class LinkRun:
    """Logs of one real-link run; times are seconds from the run's start (sender clock)."""

    scenario: LinkScenario
    constraint: str
    sent: np.ndarray
    """(n, 2): seq, t_sent."""
    arrivals: np.ndarray
    """(n, 4): seq, t_sent, t_rcv (receiver clock corrected by the true skew), size."""
    reports: np.ndarray
    """(n, 8): t, ξ, G, Δ, L, δ̂, offset estimate, offset uncertainty (B/s, s)."""


def run_link_experiment(
    scenario: LinkScenario,
    *,
    constraint: str,
    params: dict[str, float],
    workdir: Path,
    demand_bytes_per_s: float = 500_000.0,
    pace_s: float = 0.02,
    seed: int = 0,
    progress: Callable[[str], None] | None = None,
) -> LinkRun:
    """Run the probe over a fresh shaped link, following the scenario's schedule."""
    import json
    import subprocess
    import time

    from sitl.linkemu import Iperf3Background, NetnsLink

    say = progress or (lambda text: None)
    workdir.mkdir(parents=True, exist_ok=True)
    tag = f"{scenario.name}-{constraint}"
    rcv_log, snd_log = workdir / f"{tag}.rcv.csv", workdir / f"{tag}.snd.csv"
    python = sys.executable
    rates, _backgrounds = steps(*scenario.rate_bit_per_s), steps(*scenario.background_bit_per_s)
    with NetnsLink(rate_bit_per_s=rates(0.0),
                   queue_limit_bytes=scenario.queue_limit_bytes) as link:
        iperf = Iperf3Background(link)
        iperf.start_server()
        receiver = link.popen(
            link.ns_receiver,
            [python, "-m", "sitl.linkemu", "probe-receiver", "--log", str(rcv_log),
             "--clock-offset-s", repr(scenario.receiver_clock_offset_s)],
            stdout=subprocess.PIPE, text=True,
        )
        _wait_ready(receiver, "receiver")
        sender = link.popen(
            link.ns_sender,
            [python, "-m", "sitl.linkemu", "probe-sender", "--log", str(snd_log),
             "--constraint", constraint, "--params", json.dumps(params),
             "--demand-bytes-per-s", repr(demand_bytes_per_s), "--pace-s", repr(pace_s),
             "--duration-s", repr(scenario.duration_s), "--seed", str(seed)],
            stdout=subprocess.PIPE, stdin=subprocess.PIPE, text=True,
        )
        _wait_ready(sender, "sender")  # imports done; now agree on the start time
        t0 = time.time() + 0.5
        assert sender.stdin is not None
        sender.stdin.write(f"{t0!r}\n")
        sender.stdin.flush()
        events = sorted(
            [(t, "rate", v) for t, v in scenario.rate_bit_per_s if t > 0]
            + [(t, "bg", v) for t, v in scenario.background_bit_per_s]
        )
        for t, kind, value in events:
            delay = t0 + t - time.time()
            if delay > 0:
                time.sleep(delay)
            if kind == "rate":
                link.set_rate(value)
                say(f"  t={t:5.1f}s  {tag}: link rate -> {value / 1e6:.2f} Mbit/s")
            elif value > 0:
                iperf.start(rate_bit_per_s=value, duration_s=scenario.duration_s - t + 1)
                say(f"  t={t:5.1f}s  {tag}: iperf3 UDP background -> {value / 1e6:.2f} Mbit/s")
            else:
                iperf.stop()
        remaining = t0 + scenario.duration_s + 15 - time.time()
        if sender.wait(timeout=max(1.0, remaining)) != 0:
            raise RuntimeError(f"probe sender failed with exit code {sender.returncode}")
        time.sleep(0.3)  # last datagrams drain
        receiver.terminate()
        receiver.wait(timeout=5)
        iperf.stop()
    return _load_run(scenario, constraint, snd_log, rcv_log, t0)


def _wait_ready(proc: Any, what: str) -> None:
    line = proc.stdout.readline() if proc.stdout is not None else ""
    if line.strip() != "ready":
        raise RuntimeError(f"probe {what} did not start (exit code {proc.poll()})")


def _load_run(scenario: LinkScenario, constraint: str, snd_log: Path, rcv_log: Path,
              t0: float) -> LinkRun:
    sent, reports = [], []
    for line in snd_log.read_text().splitlines():
        kind, *fields = line.split(",")
        if kind == "S":
            sent.append((float(fields[0]), float(fields[1]) - t0))
        elif kind == "R":
            values = [float(v) for v in fields]
            values[0] -= t0
            reports.append(values)
    skew = scenario.receiver_clock_offset_s
    arrivals = [
        (float(a), float(b) - t0, float(c) - skew - t0, float(d))
        for a, b, c, d in (line.split(",") for line in rcv_log.read_text().splitlines())
    ]
    return LinkRun(
        scenario=scenario,
        constraint=constraint,
        sent=np.asarray(sent, dtype=np.float64).reshape(-1, 2),
        arrivals=np.asarray(arrivals, dtype=np.float64).reshape(-1, 4),
        reports=np.asarray(reports, dtype=np.float64).reshape(-1, 8),
    )


@dataclass(frozen=True, slots=True, kw_only=True)
class PhaseMetrics:
    """Targets of one phase (between two steps) of a real-link run."""

    t_start: float
    t_end: float
    left_bytes_per_s: float
    """Payload rate the link has left for the application (capacity − background)."""
    share: float
    """Steady-state application goodput / left (after ``settle_s``)."""
    p95_queueing_s: float
    """95th percentile of (latency − phase minimum latency), steady state."""
    loss: float
    """Share of application packets sent in steady state that never arrived."""
    recovery_s: float
    """Time from the step to the end of the first 1-s bin meeting both targets again."""


def _goodput(arrivals: np.ndarray, t_a: float, t_b: float) -> float:
    """Application payload bytes per second received in [t_a, t_b)."""
    rcv = arrivals[:, 2]
    return float(arrivals[(rcv >= t_a) & (rcv < t_b), 3].sum()) / (t_b - t_a)


def _p95_queueing(arrivals: np.ndarray, base_s: float, t_a: float, t_b: float) -> float:
    """95th percentile of latency − base of packets sent in [t_a, t_b) (NaN if none)."""
    m = (arrivals[:, 1] >= t_a) & (arrivals[:, 1] < t_b)
    if not m.any():
        return math.nan
    return float(np.percentile(arrivals[m, 2] - arrivals[m, 1] - base_s, 95))


def phase_metrics(run: LinkRun, *, settle_s: float = 5.0, share_target: float = 0.85,
                  delay_target_s: float = 0.1, bin_s: float = 1.0) -> list[PhaseMetrics]:
    """Per phase: steady-state goodput share, p95 queueing delay, loss, recovery time.

    Steady state is the phase after ``settle_s``; whether the targets *hold* is judged there.
    Recovery is first passage: the end of the first ``bin_s`` bin after the step (bins
    aligned on the step) whose goodput is ≥ ``share_target`` of what the link has left and
    whose p95 queueing delay is < ``delay_target_s`` (infinite if no bin does).
    """
    scenario, arrivals = run.scenario, run.arrivals
    bounds = [*scenario.step_times, scenario.duration_s]
    received = {int(s) for s in arrivals[:, 0]}
    out = []
    for t_start, t_end in itertools.pairwise(bounds):
        left = scenario.left_bytes_per_s(t_start)
        in_phase = (arrivals[:, 1] >= t_start) & (arrivals[:, 1] < t_end)
        latency = arrivals[in_phase, 2] - arrivals[in_phase, 1]
        base = float(latency.min()) if latency.size else math.nan
        a = min(t_start + settle_s, t_end)
        steady_sent = run.sent[(run.sent[:, 1] >= a) & (run.sent[:, 1] < t_end), 0]
        lost = sum(1 for s in steady_sent if int(s) not in received)
        recovery = 0.0 if t_start == 0.0 else math.inf
        t = t_start
        while t_start > 0.0 and t + bin_s <= t_end + 1e-9:
            if (_goodput(arrivals, t, t + bin_s) >= share_target * left
                    and _p95_queueing(arrivals, base, t, t + bin_s) < delay_target_s):
                recovery = t + bin_s - t_start
                break
            t += bin_s
        out.append(PhaseMetrics(
            t_start=t_start, t_end=t_end, left_bytes_per_s=left,
            share=_goodput(arrivals, a, t_end) / left if t_end > a and left > 0 else math.nan,
            p95_queueing_s=_p95_queueing(arrivals, base, a, t_end) if t_end > a else math.nan,
            loss=lost / len(steady_sent) if len(steady_sent) else math.nan,
            recovery_s=recovery,
        ))
    return out


# --------------------------------------------------------------------------------------------
# The study: figure 6.5 and RFC 8867 5.1 on the model (and optionally on a real link).

MBIT = 125_000.0
"""Bytes per second in one Mbit/s."""


def figure_6_5_runs(*, seed: int = 1, alpha_bytes_per_s: float = 0.1 * MBIT,
                    learning_rate: float = 0.01) -> dict[str, SimTrace]:
    """Figure 6.5 on the model: on/off demand every 25 s, background 0.1 -> 0.25 Mbit/s."""
    on_off = steps(*[(25.0 * k + dt, level) for k in range(4)
                     for dt, level in ((0.0, 1.5 * MBIT), (15.0, 0.08 * MBIT))])
    background = steps((0.0, 0.1 * MBIT), (50.0, 0.25 * MBIT))
    constraints: dict[str, GoodputConstraint] = {
        "adaptive": make_constraint("adaptive", alpha_bytes_per_s=alpha_bytes_per_s,
                                    learning_rate=learning_rate,
                                    initial_intercept_bytes_per_s=0.3 * MBIT),
        "aimd": make_constraint("aimd", alpha_bytes_per_s=alpha_bytes_per_s,
                                initial_bytes_per_s=0.4 * MBIT),
    }
    return {
        name: simulate(c, duration_s=100.0, rng=np.random.default_rng(seed),
                       demand_bytes_per_s=on_off, background_bytes_per_s=background)
        for name, c in constraints.items()
    }


def rfc8867_model_runs(*, seed: int = 1, alpha_bytes_per_s: float = 0.5 * MBIT,
                       time_scale: float = 1.0) -> dict[str, SimTrace]:
    """RFC 8867 5.1 capacity schedule on the model, for adaptive, AIMD and a fixed ξ."""
    k = time_scale
    capacity = steps((0.0, MBIT), (40 * k, 2.5 * MBIT), (60 * k, 0.6 * MBIT), (80 * k, MBIT))
    link = SimLink(capacity_bytes_per_s=capacity)
    constraints: dict[str, GoodputConstraint] = {
        "adaptive": make_constraint("adaptive", alpha_bytes_per_s=alpha_bytes_per_s,
                                    learning_rate=0.02, window_s=1.0,
                                    initial_intercept_bytes_per_s=0.3 * MBIT),
        "aimd": make_constraint("aimd", alpha_bytes_per_s=alpha_bytes_per_s, window_s=1.0,
                                initial_bytes_per_s=0.4 * MBIT),
        "fixed": ObservedConstant(limit_bytes_per_s=0.8 * MBIT, window_s=1.0),
    }
    return {
        name: simulate(c, duration_s=100.0 * k, rng=np.random.default_rng(seed), link=link,
                       demand_bytes_per_s=steps((0.0, 4 * MBIT)))
        for name, c in constraints.items()
    }


def write_trace_csv(trace: SimTrace, path: Path) -> None:
    columns = trace.columns()
    with path.open("w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f)
        writer.writerow(list(columns))
        writer.writerows(zip(*columns.values(), strict=True))


def _binned_goodput(trace: SimTrace, duration_s: float, bin_s: float = 1.0
                    ) -> tuple[np.ndarray, np.ndarray]:
    edges = np.arange(int(duration_s // bin_s) + 1) * bin_s
    rcv = np.array([r for _, r, _ in trace.sent if r is not None], dtype=np.float64)
    size = np.array([s for _, r, s in trace.sent if r is not None], dtype=np.float64)
    total, _ = np.histogram(rcv, bins=edges, weights=size)
    return edges[:-1] + bin_s / 2, total / bin_s


def plot_model_runs(runs: dict[str, SimTrace], path: Path, *, title: str,
                    reference: str = "background") -> None:
    """Figure 6.5 style: per constraint, ξ, application goodput and background (Mbit/s)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(runs), 1, figsize=(9, 2.8 * len(runs)), sharex=True,
                             squeeze=False)
    for ax, (name, trace) in zip(axes[:, 0], runs.items(), strict=True):
        t = np.asarray(trace.t)
        duration = float(t.max()) if len(t) else 0.0
        centers, goodput = _binned_goodput(trace, duration)
        ax.plot(t, np.asarray(trace.xi_bytes_per_s) * 8 / 1e6, label="constraint ξ", lw=1.6)
        ax.plot(centers, goodput * 8 / 1e6, "--", label="application goodput", lw=1.2)
        if reference == "background":
            ax.plot(t, np.asarray(trace.background_bytes_per_s) * 8 / 1e6, ":",
                    label="background", lw=1.4)
        else:
            ax.plot(t, np.asarray(trace.capacity_bytes_per_s) * 8 / 1e6, ":",
                    label="link capacity", lw=1.4)
        ax.set_ylabel("Mbit/s")
        ax.set_title(name, loc="left", fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="upper right")
    axes[-1, 0].set_xlabel("time (s)")
    fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_link_runs(runs: Sequence[LinkRun], path: Path) -> None:
    """Real-link runs: ξ, goodput and what the link has left (top); latency (bottom)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(runs), 2, figsize=(12, 2.8 * len(runs)), squeeze=False)
    for row, run in zip(axes, runs, strict=True):
        duration = run.scenario.duration_s
        grid = np.linspace(0.0, duration, 500)
        left = [run.scenario.left_bytes_per_s(t) * 8 / 1e6 for t in grid]
        edges = np.arange(0.0, duration + 0.5, 0.5)
        total, _ = np.histogram(run.arrivals[:, 2], bins=edges, weights=run.arrivals[:, 3])
        row[0].plot(run.reports[:, 0], run.reports[:, 1] * 8 / 1e6, label="constraint ξ")
        row[0].plot(edges[:-1] + 0.25, total / 0.5 * 8 / 1e6, "--", label="app goodput")
        row[0].plot(grid, left, ":", label="link left (capacity − background)")
        row[0].set_ylabel("Mbit/s")
        row[0].set_title(f"{run.scenario.name}: {run.constraint}", loc="left", fontsize=10)
        row[0].legend(fontsize=7, loc="upper right")
        row[0].grid(alpha=0.3)
        latency = (run.arrivals[:, 2] - run.arrivals[:, 1]) * 1000
        row[1].plot(run.arrivals[:, 1], latency, ".", ms=1.5)
        row[1].set_ylabel("one-way latency (ms)")
        row[1].grid(alpha=0.3)
        for ax in row:
            ax.set_xlabel("time (s)")
            for t in run.scenario.step_times[1:]:
                ax.axvline(t, color="grey", lw=0.8, alpha=0.6)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_link_csv(run: LinkRun, path: Path) -> None:
    with path.open("w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f)
        writer.writerow(["t_s", "xi_bytes_per_s", "goodput_bytes_per_s", "backlog_bytes_per_s",
                         "mean_latency_s", "base_latency_s", "clock_offset_s",
                         "clock_offset_uncertainty_s"])
        writer.writerows(run.reports.tolist())


def main(argv: list[str]) -> int:
    """``uav-sitl study adaptive-vs-aimd --out DIR [--real] [--time-scale K]``."""
    parser = argparse.ArgumentParser(
        prog="uav-sitl study adaptive-vs-aimd",
        description="Thesis figure 6.5 (adaptive constraint vs AIMD) and RFC 8867 test 5.1 "
                    "on a packet-level link model; with --real also on a kernel link.",
    )
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--time-scale", type=float, default=1.0,
                        help="compress the RFC 8867 schedule (0.5: 50 s instead of 100 s)")
    parser.add_argument("--real", action="store_true",
                        help="also run the RFC schedule over network namespaces (root)")
    args = parser.parse_args(argv)
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    print("figure 6.5 on the link model (adaptive, AIMD) ...", flush=True)
    fig65 = figure_6_5_runs(seed=args.seed)
    for name, trace in fig65.items():
        write_trace_csv(trace, out / f"fig6_5_{name}.csv")
    plot_model_runs(fig65, out / "fig6_5.png",
                    title="Figure 6.5 (model): constraint, application goodput, background")
    print("RFC 8867 test 5.1 on the link model (adaptive, AIMD, fixed) ...", flush=True)
    rfc = rfc8867_model_runs(seed=args.seed, time_scale=args.time_scale)
    for name, trace in rfc.items():
        write_trace_csv(trace, out / f"rfc8867_model_{name}.csv")
    plot_model_runs(rfc, out / "rfc8867_model.png", reference="capacity",
                    title="RFC 8867 5.1 capacity schedule (model)")
    for name, trace in {**{f"fig6_5 {k}": v for k, v in fig65.items()},
                        **{f"rfc8867 {k}": v for k, v in rfc.items()}}.items():
        xi = np.asarray(trace.xi_bytes_per_s)
        print(f"  {name:18s} mean ξ {xi.mean() * 8 / 1e6:6.3f} Mbit/s, "
              f"CV {xi.std() / xi.mean():.3f}")
    if args.real:
        from sitl.linkemu import missing_requirements

        reason = missing_requirements()
        if reason is not None:
            print(f"--real skipped: {reason}", file=sys.stderr)
            return 1
        scenario = rfc8867_5_1(time_scale=args.time_scale)
        runs = []
        for name, params in REAL_LINK_CONSTRAINTS.items():
            print(f"RFC 8867 5.1 on a real link: {name} ({scenario.duration_s:g} s) ...",
                  flush=True)
            kind = "constant" if name == "fixed" else name
            run = run_link_experiment(scenario, constraint=kind, params=dict(params),
                                      workdir=out / "real", progress=print)
            run.constraint = name
            write_link_csv(run, out / f"rfc8867_real_{name}.csv")
            runs.append(run)
        plot_link_runs(runs, out / "rfc8867_real.png")
    print(f"wrote CSV and PNG to {out}")
    return 0


REAL_LINK_CONSTRAINTS: dict[str, dict[str, float]] = {
    "adaptive": {"window_s": 0.5, "alpha_bytes_per_s": 62_500.0, "learning_rate": 0.1,
                 "min_coef": 0.3, "backlog_clip": 2.0, "min_base_latency_s": 0.01,
                 "min_bytes_per_s": 6_250.0},
    "aimd": {"window_s": 0.5, "alpha_bytes_per_s": 62_500.0, "min_base_latency_s": 0.01,
             "min_bytes_per_s": 6_250.0},
    "fixed": {"window_s": 0.5, "limit_bytes_per_s": 115_000.0},
}
"""Constraints compared on the real 1 Mbit/s link (fixed: tuned to the base capacity)."""
