"""Link statistics learned from receiver reports (thesis ch. 6.1, eq. 6.2, 6.4, 6.5).

Everything here is sans-I/O: samples and round trips come in as values, time as ``now``.

Windows (eq. 6.1) are anchored at the newest *reception* time a report has told us about,
not at the sender's ``now``: a report lists everything that arrived up to the moment it was
written, so the window ``(t_rcv_newest - T, t_rcv_newest]`` is complete when the report
is processed, whereas a window over ``t_sent`` ending at ``now`` would be missing every
message still in flight and would read a congested link as an idle one.

One-way latency is ``t_rcv - t_sent`` on two different clocks. The raw difference is stored
and the current clock-offset estimate (receiver clock minus sender clock) is subtracted when
the statistics are read, so a better offset estimate corrects old samples too and the
base-latency minimum and the mean latency are always on the same footing.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Self

from companion.middleware.errors import LinkStatsError

__all__ = [
    "ClockOffset",
    "ClockOffsetEstimator",
    "LinkSample",
    "LinkStats",
    "RoundTrip",
    "WindowStats",
]


@dataclass(frozen=True, slots=True, kw_only=True)
class LinkSample:
    """One delivered message as learned from a receiver report."""

    t_sent: float
    """When the sender put it on the link (sender's clock, seconds)."""
    t_rcv: float
    """When the receiver got it (receiver's clock, seconds)."""
    size: int
    """Payload bytes."""
    sender: str = ""
    seq: int = -1
    own: bool = True
    """False: another agent's message on the same link, listed in this agent's reports. It
    counts in the fleet's goodput when :class:`LinkStats` has ``fleet_goodput``, never in
    latency: its send time is on another agent's clock, whose offset is not known here."""


@dataclass(frozen=True, slots=True, kw_only=True)
class WindowStats:
    """The link as seen through the last window of length ``window_s``."""

    t_end: float
    """End of the window: newest reception time known (receiver clock, s)."""
    window_s: float
    """Window length T (s)."""
    n_messages: int
    """Messages received in the window, |W|."""
    goodput_bytes_per_s: float
    """‖W‖_G = Σ size / T (eq. 6.2), payload bytes per second."""
    mean_latency_s: float
    """‖W‖_L = mean(t_rcv - t_sent) (eq. 6.5), corrected by the clock offset."""
    base_latency_s: float
    """δ̂: minimum corrected latency over the last ``base_window_s`` (BBR-like)."""
    backlog_bytes_per_s: float
    """‖W‖_Δ = ‖W‖_G·‖W‖_L/δ̂ − ‖W‖_G (eq. 6.4), bytes per second (≥ 0; δ̂ floored)."""
    warm: bool
    """True once observations span at least one whole window (before, G is too low)."""
    queueing_s: float | None = None
    """With a link rate: the mean per-message queueing delay, latency − δ̂ − size/rate
    (each at least 0). None: the thesis' ‖W‖_L − δ̂."""
    lost: int = 0
    """This agent's messages the report of this window showed lost (the constraint's
    ``loss_is_congestion``; its backlog is then infinite: the queue overflowed)."""

    @property
    def queueing_delay_s(self) -> float:
        """Mean latency above the base latency, ‖W‖_L − δ̂ (without the messages'
        transmission times when the link rate is known)."""
        if self.queueing_s is not None:
            return self.queueing_s
        return self.mean_latency_s - self.base_latency_s


@dataclass(frozen=True, slots=True, kw_only=True)
class RoundTrip:
    """One NTP-style exchange: a message out, and the report that acknowledged it back.

    ``t_sent``/``t_rcv`` are on the local (sender) clock, ``t_remote_rcv``/``t_remote_sent``
    on the remote (receiver) clock.
    """

    t_sent: float
    """When the acknowledged message left (local clock, s): NTP t1."""
    t_remote_rcv: float
    """When the receiver got that message (remote clock, s): NTP t2."""
    t_remote_sent: float
    """When the receiver sent the report (remote clock, s): NTP t3."""
    t_rcv: float
    """When the report arrived here (local clock, s): NTP t4."""

    def __post_init__(self) -> None:
        for name in ("t_sent", "t_remote_rcv", "t_remote_sent", "t_rcv"):
            if not math.isfinite(getattr(self, name)):
                raise LinkStatsError(f"{name} must be finite, got {getattr(self, name)}")
        if self.t_rcv < self.t_sent:
            raise LinkStatsError(f"t_rcv {self.t_rcv} is before t_sent {self.t_sent}")
        if self.t_remote_sent < self.t_remote_rcv:
            raise LinkStatsError(
                f"t_remote_sent {self.t_remote_sent} is before t_remote_rcv {self.t_remote_rcv}"
            )

    @property
    def offset_s(self) -> float:
        """θ = ((t2 − t1) + (t3 − t4)) / 2: remote clock minus local clock (RFC 5905)."""
        return ((self.t_remote_rcv - self.t_sent) + (self.t_remote_sent - self.t_rcv)) / 2.0

    @property
    def delay_s(self) -> float:
        """Round-trip delay without the receiver's hold time: (t4 − t1) − (t3 − t2)."""
        return max(0.0, (self.t_rcv - self.t_sent) - (self.t_remote_sent - self.t_remote_rcv))


@dataclass(frozen=True, slots=True, kw_only=True)
class ClockOffset:
    """Estimated offset between the receiver's and the sender's clocks."""

    offset_s: float
    """Receiver clock minus sender clock (s); subtract it from ``t_rcv - t_sent``."""
    uncertainty_s: float
    """Half the round-trip delay of the sample used: the true offset is within ± this."""
    n_samples: int
    """Round trips in the history the estimate was chosen from."""


class ClockOffsetEstimator:
    """NTP-style clock offset from report round trips, using the lowest-delay sample.

    Queueing makes a round trip asymmetric and biases its offset by up to half its delay,
    so, as NTP's clock filter does (RFC 5905 sec. 10), the estimate is the offset of the
    round trip with the smallest delay among those of the last ``history_s`` seconds.
    The uncertainty is that sample's delay / 2: a bound, not a standard deviation.

    Parameters
    ----------
    history_s
        How long a round trip stays a candidate (local clock, s). Long enough to contain a
        moment with empty queues, short enough to follow clock drift.
    """

    def __init__(self, *, history_s: float = 60.0) -> None:
        if not history_s > 0:
            raise LinkStatsError(f"history_s must be > 0, got {history_s}")
        self.history_s = history_s
        # Monotonic deque (t_rcv, delay, offset) with increasing delays: the front is the
        # minimum-delay round trip of the history (sliding-window minimum).
        self._best: deque[tuple[float, float, float]] = deque()
        self._times: deque[float] = deque()
        self.rejected = 0
        """Round trips ignored because their delay was negative (impossible stamps)."""

    def update(self, round_trip: RoundTrip) -> Self:
        """Add one round trip (assumed to arrive in order of ``t_rcv``).

        A round trip shorter than the receiver's hold time ((t4 − t1) < (t3 − t2)) cannot
        happen; a late t1/t3 or an early t4 stamp made it (a process that stamped a report's
        arrival before draining its socket, on a loaded host). Its delay would read as 0,
        the best possible, and its offset, wrong by up to the hold time, would win for
        ``history_s``: such round trips are counted in ``rejected`` and ignored.
        """
        t = round_trip.t_rcv
        delay = (t - round_trip.t_sent) - (round_trip.t_remote_sent - round_trip.t_remote_rcv)
        if delay < 0:
            self.rejected += 1
            return self
        while self._best and self._best[-1][1] >= delay:
            self._best.pop()
        self._best.append((t, delay, round_trip.offset_s))
        self._times.append(t)
        horizon = t - self.history_s
        while self._best and self._best[0][0] <= horizon:
            self._best.popleft()
        while self._times and self._times[0] <= horizon:
            self._times.popleft()
        return self

    def get(self) -> ClockOffset | None:
        """The current estimate, or None before the first round trip."""
        if not self._best:
            return None
        _, delay, offset = self._best[0]
        return ClockOffset(offset_s=offset, uncertainty_s=delay / 2.0, n_samples=len(self._times))


class LinkStats:
    """Windowed goodput, latency, base latency and backlog (eq. 6.2, 6.4, 6.5).

    ``update(sample, now=...)`` is O(1) amortised: sums are kept incrementally and δ̂ is a
    sliding-window minimum (monotonic deque), so it can run for every reported message.

    Parameters
    ----------
    window_s
        T, the window length (thesis: 2.5 s in simulation, 0.5 s on robots).
    base_window_s
        How long a latency minimum is remembered. A fixed minimum would freeze after a
        route change; BBR keeps its min-RTT for 10 s, which is the default here.
    clock
        Clock-offset estimator; when it has an estimate, latencies are corrected by it.
    assumed_offset_s
        Offset used while ``clock`` has no estimate (0: clocks assumed synchronised).
    min_base_latency_s
        Floor for the divisor δ̂ of eq. 6.4: the least one-way latency a real radio link
        has (air time of a packet). Without it, a path with microsecond base latency (a
        veth pair, loopback) turns sub-millisecond jitter into a backlog of several times
        the goodput, and a clock error that drives δ̂ to ≤ 0 would divide by zero.
    fleet_goodput
        False (thesis-exact as the reference code read it): only this agent's messages
        count. True: the goodput ‖W‖_G is the whole fleet's on the link, every reported
        message (eq. 6.2 sums over all messages exchanged), because ξ is the fleet's budget:
        each agent plans the fleet's window with it. Fitted to one drone's own goodput, ξ
        settled near a quarter of the link in the 4-drone demo (docs/adaptive.md).
    link_rate_bytes_per_s
        0 (thesis-exact): a message's latency above δ̂ is all queueing. Above 0, the link's
        rate: a message of ``size`` bytes needs size/rate to get through even on an empty
        link, so its queueing is latency − δ̂ − size/rate (at least 0), and eq. 6.4's
        divisor is the window's mean latency on an empty link, δ̂ + mean(size/rate). On
        the demo's 50 kB/s link a 6 kB camera frame takes 120 ms to transmit; with δ̂ at
        the 10 ms floor that read as 11 times the goodput in the queue at 15 % load.
    """

    def __init__(
        self,
        *,
        window_s: float = 2.5,
        base_window_s: float = 10.0,
        clock: ClockOffsetEstimator | None = None,
        assumed_offset_s: float = 0.0,
        min_base_latency_s: float = 0.005,
        fleet_goodput: bool = False,
        link_rate_bytes_per_s: float = 0.0,
    ) -> None:
        if not window_s > 0:
            raise LinkStatsError(f"window_s must be > 0, got {window_s}")
        if not base_window_s >= window_s:
            raise LinkStatsError(
                f"base_window_s ({base_window_s}) must be >= window_s ({window_s})")
        if not min_base_latency_s > 0:
            raise LinkStatsError(f"min_base_latency_s must be > 0, got {min_base_latency_s}")
        self.window_s = window_s
        self.base_window_s = base_window_s
        self.clock = clock if clock is not None else ClockOffsetEstimator()
        self.assumed_offset_s = assumed_offset_s
        self.min_base_latency_s = min_base_latency_s
        if not (math.isfinite(link_rate_bytes_per_s) and link_rate_bytes_per_s >= 0):
            raise LinkStatsError(
                f"link_rate_bytes_per_s must be >= 0 (0: unknown), got {link_rate_bytes_per_s}")
        self.fleet_goodput = bool(fleet_goodput)
        self.link_rate_bytes_per_s = float(link_rate_bytes_per_s)
        self.counters: dict[str, int] = {"samples": 0, "duplicate": 0, "stale": 0, "invalid": 0,
                                         "stalled": 0}
        self._stalls: deque[tuple[float, float]] = deque(maxlen=8)
        """Intervals of this agent's own clock in which it did not run (:meth:`mark_stall`)."""
        self.others = 0
        """Other agents' samples counted in the goodput (``fleet_goodput``) or ignored."""
        # (t_rcv, raw latency or None for another agent's message, size, key) in arrival
        # order; keys dedupe repeated reports.
        self._window: deque[tuple[float, float | None, int, tuple[str, int] | None]] = deque()
        self._keys: set[tuple[str, int]] = set()
        self._sum_size = 0
        self._sum_latency = 0.0
        self._n_timed = 0
        # Sliding minimum of raw latency over base_window_s: (t_rcv, raw latency), increasing.
        self._min: deque[tuple[float, float]] = deque()
        self._t_first: float | None = None
        self._t_newest: float | None = None

    # -- input -----------------------------------------------------------------------------

    def update(self, sample: LinkSample, *, now: float) -> Self:
        """Learn one delivered message from a report processed at ``now`` (local clock).

        Duplicates (same sender and seq already in the window), non-finite times and
        samples older than the current window are counted and ignored.
        """
        del now  # the window is anchored at reception times; kept for the uniform API
        t_rcv, t_sent = sample.t_rcv, sample.t_sent
        if not (math.isfinite(t_rcv) and math.isfinite(t_sent)) or sample.size < 0:
            self.counters["invalid"] += 1
            return self
        if not sample.own and not self.fleet_goodput:
            self.others += 1
            return self
        if sample.own and any(a <= t_sent <= b for a, b in self._stalls):
            self.counters["stalled"] += 1  # its latency is this agent's stall, not the link's
            return self
        if self._t_newest is not None and t_rcv <= self._t_newest - self.window_s:
            self.counters["stale"] += 1
            return self
        if self._t_newest is None or t_rcv > self._t_newest:
            self._t_newest = t_rcv
            self._prune()  # first, so a repeat of a message that just left is not a duplicate
        key = (sample.sender, sample.seq) if sample.seq >= 0 else None
        if key is not None and key in self._keys:
            self.counters["duplicate"] += 1
            return self
        if self._t_first is None:
            self._t_first = t_rcv
        if key is not None:
            self._keys.add(key)
        self._sum_size += sample.size
        if not sample.own:  # the fleet's goodput only (see LinkSample.own)
            self.others += 1
            self._window.append((t_rcv, None, sample.size, key))
            return self
        self.counters["samples"] += 1
        raw = t_rcv - t_sent
        self._window.append((t_rcv, raw, sample.size, key))
        self._sum_latency += raw
        self._n_timed += 1
        while self._min and self._min[-1][1] >= raw:
            self._min.pop()
        self._min.append((t_rcv, raw))
        return self

    def mark_stall(self, t_from: float, t_to: float) -> Self:
        """This agent did not run between ``t_from`` and ``t_to`` (its clock): what it had
        stamped and queued left late, so its messages sent in there say nothing about the
        link and are not learned from (a 4 s SIGSTOP of the companion read as 4 s of
        queueing and cut ξ by 70 % for 15 s: docs/companion.md)."""
        if t_to >= t_from:
            self._stalls.append((t_from, t_to))
        return self

    def on_round_trip(self, round_trip: RoundTrip) -> Self:
        """Feed one report round trip to the clock-offset estimator."""
        self.clock.update(round_trip)
        return self

    def _prune(self) -> None:
        assert self._t_newest is not None
        horizon = self._t_newest - self.window_s
        while self._window and self._window[0][0] <= horizon:
            _, raw, size, key = self._window.popleft()
            self._sum_size -= size
            if raw is not None:
                self._sum_latency -= raw
                self._n_timed -= 1
            if key is not None:
                self._keys.discard(key)
        if not self._n_timed:  # re-anchor the float sum when no latency is left
            self._sum_latency = 0.0
        base_horizon = self._t_newest - self.base_window_s
        while self._min and self._min[0][0] <= base_horizon:
            self._min.popleft()

    # -- output ----------------------------------------------------------------------------

    @property
    def offset_s(self) -> float:
        """Clock offset in use (receiver minus sender clock, s)."""
        estimate = self.clock.get()
        return estimate.offset_s if estimate is not None else self.assumed_offset_s

    def get(self) -> WindowStats | None:
        """Statistics of the current window, or None before this agent's first sample in it
        (another agent's message alone says nothing about latency)."""
        if self._t_newest is None or not self._n_timed or self._t_first is None:
            return None
        n = len(self._window)
        offset = self.offset_s
        goodput = self._sum_size / self.window_s
        mean_latency = self._sum_latency / self._n_timed - offset
        base = self._min[0][1] - offset
        queueing: float | None = None
        if self.link_rate_bytes_per_s > 0:
            # Per message: its latency less the base and its own transmission time. O(|W|),
            # only with a known link rate (the thesis' path stays O(1)).
            rate, raw_base = self.link_rate_bytes_per_s, self._min[0][1]
            timed = [(raw, size / rate) for _, raw, size, _ in self._window if raw is not None]
            queueing = sum(max(0.0, raw - raw_base - tx) for raw, tx in timed) / len(timed)
            divisor = max(base + sum(tx for _, tx in timed) / len(timed),
                          self.min_base_latency_s)
            backlog = goodput * queueing / divisor
        else:
            # eq. 6.4 as G·(L − δ̂)/δ̂: identical for δ̂ > 0, and the numerator (queueing
            # delay) does not depend on the clock offset at all; only the divisor is floored.
            backlog = goodput * max(0.0, mean_latency - base) / max(base,
                                                                    self.min_base_latency_s)
        return WindowStats(
            t_end=self._t_newest,
            window_s=self.window_s,
            n_messages=n,
            goodput_bytes_per_s=goodput,
            mean_latency_s=mean_latency,
            base_latency_s=base,
            backlog_bytes_per_s=backlog,
            warm=self._t_newest - self._t_first >= self.window_s,
            queueing_s=queueing,
        )
