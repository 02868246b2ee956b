"""Real kernel link (network namespaces + tc tbf + iperf3) runs of the probe, and their metrics.

Used by ``adaptive-vs-aimd --real``, the real-link benchmark and the netns integration test.
"""

from __future__ import annotations

import itertools
import math
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sitl.study.adaptive.model import steps

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
        try:
            code = sender.wait(timeout=max(1.0, remaining))
        except subprocess.TimeoutExpired:
            # A starved host (seconds-long stalls): stop it here, so the namespaces close.
            sender.kill()
            sender.wait()
            raise RuntimeError(f"probe sender of {tag} still running 15 s after the run's "
                               "end (host starved?)") from None
        if code != 0:
            raise RuntimeError(f"probe sender failed with exit code {code}")
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
    xi_cv: float = math.nan
    """Coefficient of variation of ξ (std / mean over the reports) in steady state."""


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


def _xi_cv(reports: np.ndarray, t_a: float, t_b: float) -> float:
    """CV of ξ over the reports processed in [t_a, t_b) (NaN if fewer than two)."""
    xi = reports[(reports[:, 0] >= t_a) & (reports[:, 0] < t_b), 1]
    if xi.size < 2 or not xi.mean() > 0:
        return math.nan
    return float(xi.std() / xi.mean())


def phase_metrics(run: LinkRun, *, settle_s: float = 5.0, share_target: float = 0.85,
                  delay_target_s: float = 0.1, bin_s: float = 1.0) -> list[PhaseMetrics]:
    """Per phase: steady-state goodput share, p95 queueing delay, loss, recovery time.

    Steady state is the phase after ``settle_s``; whether the targets *hold* is judged there,
    and the CV of ξ (how smooth the constraint is) is measured there.
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
            xi_cv=_xi_cv(run.reports, a, t_end),
        ))
    return out


REAL_LINK_CONSTRAINTS: dict[str, dict[str, float]] = {
    "adaptive": {"window_s": 0.5, "alpha_bytes_per_s": 62_500.0, "learning_rate": 0.1,
                 "min_coef": 0.3, "backlog_clip": 2.0, "min_base_latency_s": 0.01,
                 "min_bytes_per_s": 6_250.0},
    "aimd": {"window_s": 0.5, "alpha_bytes_per_s": 62_500.0, "min_base_latency_s": 0.01,
             "min_bytes_per_s": 6_250.0},
    "fixed": {"window_s": 0.5, "limit_bytes_per_s": 115_000.0},
}
"""Constraints compared on the real 1 Mbit/s link (fixed: tuned to the base capacity).
``adaptive-smooth`` (use-weighted steps and the knee memory) runs with the adaptive ones."""
REAL_LINK_CONSTRAINTS["adaptive-smooth"] = REAL_LINK_CONSTRAINTS["adaptive"]

LINK_CONSTRAINT_KINDS = {"fixed": "constant"}
"""The registry name of a compared constraint, where it is not its own name."""
