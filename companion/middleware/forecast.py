"""Forecast of future messages (thesis ch. 5.1) and robust latency estimates.

The optimiser needs the generation times of messages that do not exist yet. As in the thesis,
streams are assumed periodic: per (sender, type) stream the period and the phase are estimated
from observed generation times, and the stream is extrapolated over the planning horizon.
Everything is sans-I/O: observations come in with their own timestamps.
"""

from __future__ import annotations

import cmath
import itertools
import math
import zlib
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from utility_specs.message import Message, Version

__all__ = ["LatencyEstimator", "StreamForecaster", "StreamKeyT"]

StreamKeyT = tuple[str, str]
"""(sender, type): one periodic stream of one agent."""

_HISTORY = 32
"""Observations kept per stream: forecasting cost does not grow with mission length."""

_SPREAD_MIN = 6
"""Valued observations a stream needs before its forecasts spread over their worths."""
_SPREAD_REL = 0.05
"""Spread only when the 10th-90th percentile range of worths exceeds this share of the
median: a stream whose messages are all worth the same keeps its one forecast copy."""
_GOLDEN = 0.6180339887498949
"""Quantile step between consecutive forecast messages (any run of them covers the range)."""
STREAM_SEQ = "frame"
"""Data field of a per-stream sequence number (the companion's camera frame index): it
counts the periods between two heard messages of that stream alone, as ``seq`` cannot
(one counter for all of a sender's types). Round 11 (docs/middleware.md)."""


@dataclass(slots=True)
class _Stream:
    times: deque[float] = field(default_factory=lambda: deque(maxlen=_HISTORY))
    seqs: deque[int] = field(default_factory=lambda: deque(maxlen=_HISTORY))
    counts: deque[int | None] = field(default_factory=lambda: deque(maxlen=_HISTORY))
    """The messages' own per-stream numbers (:data:`STREAM_SEQ`), None where absent."""
    sizes: deque[int] = field(default_factory=lambda: deque(maxlen=8))
    last: Message | None = None
    """The newest known message (its data and versions are what forecasts carry)."""
    cached: tuple[float | None, float] | None = None
    """(period, anchor) until the next observation."""
    pool: deque[tuple[float, Message]] = field(default_factory=lambda: deque(maxlen=_HISTORY))
    """(worth, message) of the recent observations: the empirical distribution of what the
    stream's next messages may carry."""
    ranked: list[tuple[float, Message]] | None = None
    """``pool`` by worth when it is spread enough to matter (cached), else None."""


class StreamForecaster:
    """Period and phase per stream from generation times; predicted messages over a horizon.

    Observations may have gaps (dropped messages are never heard of), so the period is not the
    mean gap. When the stream is its sender's only one, sequence numbers count the periods
    between observations. Otherwise each gap is divided by its estimated number of periods
    ``round(gap / p20)``
    (p20, the 20th percentile of gaps, is close to one period even when most messages are
    missing) and the period is Σ gap / Σ periods. The phase is the circular mean of
    ``t_gen mod period`` (as an angle, so that phases near 0 and near the period average
    correctly instead of to period / 2).

    A heartbeat type (``heartbeats``: sent whatever the optimiser decides, and at once on a
    new state) is never dropped but has extra, early messages: its period is its long gaps
    (:func:`_heartbeat_period`).
    """

    __slots__ = ("_streams", "assume_fleet_period", "declared", "heartbeats", "pool_span_s",
                 "prior_period", "worth")

    def __init__(self, *, assume_fleet_period: bool = True,
                 worth: Callable[[Message], float | None] | None = None,
                 heartbeats: frozenset[str] = frozenset(),
                 declared: Mapping[str, float] | None = None) -> None:
        self._streams: dict[StreamKeyT, _Stream] = {}
        self.assume_fleet_period = assume_fleet_period
        self.declared: Mapping[str, float] = declared or {}
        """Type -> the mission's nominal period (``[types.X] period_s``): a stream heard of
        only once repeats at it rather than at :attr:`prior_period`, which the first
        messages of a mission do not have yet (round 15: such a stream was not forecast at
        all, and the next agent took the window its next message needed)."""
        self.heartbeats = heartbeats
        """Types every agent sends whatever it decides (the companion's status)."""
        self.worth = worth
        """What a message is worth (e.g. its utility integral over a few seconds). Given,
        the forecasts of a stream whose recent messages differ in worth carry the data of
        those messages, one quantile each, instead of the last message's data (see
        :meth:`forecast`). None: every forecast carries the last data (the thesis' model)."""
        self.pool_span_s: float | None = None
        """Spread only over the observations generated within this many seconds of a
        stream's newest one (None: its last :data:`_HISTORY`). Another drone's stream is
        heard a frame a second or less, so its 32 observations span the mission: when the
        red drone's frames turned red, the others still drew its forecasts mostly from its
        plain frames, worth ~0 over its red base, and took the window (docs/adaptive.md,
        "The red drone's precedence")."""
        self.prior_period: float | None = None
        """Median period of the streams seen at least twice (refreshed by :meth:`refresh`);
        a stream heard of only once is assumed to repeat at it (``assume_fleet_period``)."""

    def refresh(self) -> None:
        """Recompute :attr:`prior_period` (once per decision, not per stream)."""
        if not self.assume_fleet_period:
            self.prior_period = None
            return
        periods = sorted(p for p in (self._estimate(k)[0] for k in self._streams) if p is not None)
        self.prior_period = periods[len(periods) // 2] if periods else None

    def observe(self, message: Message) -> None:
        """Learn from one known message (own generated, or another agent's delivered)."""
        stream = self._streams.get((message.sender, message.type))
        if stream is None:
            stream = self._streams[(message.sender, message.type)] = _Stream()
        if stream.times and abs(stream.times[-1] - message.t_gen) < 1e-9:
            return  # the same message seen twice (e.g. own send, then its delivery)
        if stream.times and message.t_gen < stream.times[-1]:
            return  # late news about an older message: the newest data stays the newest
        stream.times.append(message.t_gen)
        stream.seqs.append(message.seq)
        count = message.data.get(STREAM_SEQ)
        stream.counts.append(count if type(count) is int and count >= 0 else None)
        stream.sizes.append(_best_size(message))
        stream.last = message
        stream.cached = None
        if self.worth is not None:
            value = self.worth(message)
            if value is not None and math.isfinite(value):
                stream.pool.append((value, message))
                stream.ranked = None

    def streams(self) -> list[StreamKeyT]:
        return list(self._streams)

    def risen(self, key: StreamKeyT) -> float | None:
        """The mean worth of the stream's observations within :attr:`pool_span_s` of its
        newest over the median of all it keeps: how far its recent messages rose above its
        history (the red drone's frames, seen by the others); None when unvalued."""
        stream = self._streams.get(key)
        if stream is None or len(stream.pool) < _SPREAD_MIN:
            return None
        since = stream.pool[-1][1].t_gen - (self.pool_span_s or math.inf)
        # per unit of the carried version's quality: another drone's half frame after its
        # quarter ones is not a rise (seen: 2.0x, and the plain drones held back 2 s)
        worths = [(w / m.quality if m.quality > 0 else w, m) for w, m in stream.pool]
        recent = [w for w, m in worths if m.t_gen >= since]
        history = sorted(w for w, _ in worths)[(len(worths) - 1) // 2]
        return sum(recent) / len(recent) / history if history > 0 else None

    def type_period(self, type_name: str) -> float | None:
        """The period a stream of ``type_name`` is expected to have before it shows its own:
        the median of the known streams of the type, else the declared one, else None."""
        known = sorted(p for key in self._streams if key[1] == type_name
                       if (p := self.period(key)) is not None)
        if known:
            return known[len(known) // 2]
        return self.declared.get(type_name)

    def period(self, key: StreamKeyT) -> float | None:
        """Estimated period in seconds, ``None`` before two observations."""
        stream = self._streams.get(key)
        if stream is None or len(stream.times) < 2:
            return None
        times = list(stream.times)
        if key[1] in self.heartbeats:
            return _heartbeat_period(times)
        counts = list(stream.counts)
        if _increasing(counts):
            first, newest = counts[0], counts[-1]
            assert first is not None and newest is not None
            # Round 11: the stream numbers its own messages (a camera's frame index), so
            # the steps count its periods even when most frames were dropped. Without it
            # the others forecast a drone's frames at the rate they arrive (one per ~2 s
            # for 3 frames/s), left no room for its red frames, and took the window.
            return (times[-1] - times[0]) / (newest - first)
        seqs = list(stream.seqs)
        steps = seqs[-1] - seqs[0]
        if steps > 0 and self._alone(key) and _seq_paced(times, seqs):
            # The sender's only known stream, and its sequence numbers advance in step with
            # time: they count the periods in between, which tells a 3 s stream from a 1 s
            # stream of which every third message arrived. A sender numbers all its
            # messages with one counter (the companion does), so seq steps also count its
            # other, unheard streams (images among telemetry): then the time per step varies
            # from gap to gap and the seqs say nothing about this stream's period.
            return (times[-1] - times[0]) / steps
        gaps = [b - a for a, b in itertools.pairwise(times) if b - a > 1e-9]
        if not gaps:
            return None
        ordered = sorted(gaps)
        base = ordered[int(0.2 * (len(ordered) - 1))]
        periods = sum(max(1, round(g / base)) for g in gaps)
        return sum(gaps) / periods

    def _alone(self, key: StreamKeyT) -> bool:
        return sum(1 for sender, _ in self._streams if sender == key[0]) == 1

    def _estimate(self, key: StreamKeyT) -> tuple[float | None, float]:
        """(period, anchor), cached until the stream's next observation."""
        stream = self._streams[key]
        if stream.cached is None:
            estimate = self.period(key)
            anchor = self._anchor(key, estimate) if estimate is not None else 0.0
            stream.cached = (estimate, anchor)
        return stream.cached

    def predict(self, key: StreamKeyT, *, t_from: float, t_to: float) -> list[float]:
        """Predicted generation times in (t_from, t_to] that are not already known.

        A time within half a period of the newest known generation time is that message,
        not a new one: a known message is never forecast again.
        """
        stream = self._streams.get(key)
        if stream is None or not stream.times:
            return []
        period, ref = self._estimate(key)
        if period is None:
            period = self.declared.get(key[1], self.prior_period)
            if period is None:
                return []
            ref = stream.times[-1]
        newest = stream.times[-1]
        start = max(t_from, newest + 0.5 * period)
        k = math.floor((start - ref) / period) + 1
        out: list[float] = []
        t = ref + k * period
        while t <= t_to:
            if t > start - 1e-12:
                out.append(t)
            k += 1
            t = ref + k * period
        return out

    def _anchor(self, key: StreamKeyT, period: float) -> float:
        """A generation time of the stream's phase near its newest observation."""
        stream = self._streams[key]
        ref = stream.times[-1]
        total = sum(
            (cmath.exp(2j * math.pi * (((t - ref) % period) / period)) for t in stream.times),
            start=0j,
        )
        angle = cmath.phase(total) if abs(total) > 1e-12 else 0.0
        offset = angle / (2 * math.pi) * period  # in (-period/2, period/2]
        return ref + offset

    def mean_size(self, key: StreamKeyT) -> int:
        stream = self._streams[key]
        return round(sum(stream.sizes) / len(stream.sizes)) if stream.sizes else 0

    def _ranked(self, stream: _Stream) -> list[tuple[float, Message]] | None:
        """The stream's valued observations by worth, or None when they are too few or all
        worth about the same (then one copy of the last message is the forecast)."""
        if self.worth is None or len(stream.pool) < _SPREAD_MIN:
            return None
        if stream.ranked is None:
            pool = list(stream.pool)
            if self.pool_span_s is not None:
                since = pool[-1][1].t_gen - self.pool_span_s
                pool = [wm for wm in pool if wm[1].t_gen >= since]
            if len(pool) < _SPREAD_MIN:
                stream.ranked = []
                return None
            ranked = sorted(pool, key=lambda wm: wm[0])
            lo = ranked[int(0.1 * (len(ranked) - 1))][0]
            mid = ranked[(len(ranked) - 1) // 2][0]
            hi = ranked[int(0.9 * (len(ranked) - 1))][0]
            stream.ranked = ranked if hi - lo > _SPREAD_REL * abs(mid) else []
        return stream.ranked or None

    def forecast(self, key: StreamKeyT, *, t_from: float, t_to: float,
                 spread: bool = True) -> list[Message]:
        """Messages predicted for (t_from, t_to]: the last known data, the recent mean size.

        With :attr:`worth`, a stream whose recent messages differ in worth (the red content of
        frames) is forecast as a draw from them rather than as copies of the last one: the
        message predicted for period ``k`` carries the data of the recent message at quantile
        ``frac(k·0.618 + stream offset)`` of worth. Any run of consecutive forecasts covers
        the distribution evenly (a low-discrepancy draw: the best of n future frames sits
        near the 1 - 1/n quantile, as it would in expectation), the draw for a given future
        message is the same at every decision (plans stay consistent), and the optimiser
        sees the value of waiting: a plain frame now competes with the redder frames the
        stream is likely to offer within the same budget, not with copies of itself.
        ``spread=False``: copies of the last message whatever :attr:`worth` says (messages
        another agent has decided already, in flight, are what it has been sending).
        """
        stream = self._streams.get(key)
        if stream is None or stream.last is None:
            return []
        last = stream.last
        size = self.mean_size(key)
        versions = _scaled_versions(last, size)
        times = self.predict(key, t_from=t_from, t_to=t_to)
        ranked = self._ranked(stream) if times and spread else None
        if ranked is not None:
            return self._spread(key, ranked, times, last, versions, size)
        out: list[Message] = []
        for i, t in enumerate(times):
            if not out or not math.isfinite(t):
                out.append(
                    Message(
                        sender=last.sender,
                        seq=-1 - i,
                        type=last.type,
                        t_gen=t,
                        size=versions[0].size if versions else size,
                        data=last.data,
                        versions=versions,
                        version=0 if versions else None,
                    )
                )
            else:  # the first one was validated; the others differ only in seq and t_gen
                out.append(_with_seq_time(out[0], -1 - i, t))
        return out

    def _spread(self, key: StreamKeyT, ranked: list[tuple[float, Message]], times: list[float],
                last: Message, versions: tuple[Version, ...], size: int) -> list[Message]:
        """Forecasts at ``times`` carrying the data of ``ranked`` at golden-ratio quantiles."""
        period = self._estimate(key)[0] or self.prior_period or 1.0
        offset = zlib.crc32(f"{key[0]}/{key[1]}".encode()) / 2**32
        template = Message(sender=last.sender, seq=-1, type=last.type, t_gen=times[0],
                           size=versions[0].size if versions else size, data=last.data,
                           versions=versions, version=0 if versions else None)
        out: list[Message] = []
        for i, t in enumerate(times):
            u = (round(t / period) * _GOLDEN + offset) % 1.0
            source = ranked[min(len(ranked) - 1, int(u * len(ranked)))][1]
            out.append(_with_data(template, -1 - i, t, source.data))
        return out

    def forget(self, older_than: float) -> None:
        """Drop streams silent since ``older_than`` (bounded memory over long missions)."""
        stale = [k for k, s in self._streams.items() if not s.times or s.times[-1] < older_than]
        for key in stale:
            del self._streams[key]


def _heartbeat_period(times: list[float]) -> float | None:
    """The period of a heartbeat: the median of its gaps of at least 0.4 x the longest.

    A heartbeat goes every period and at once on a new state, which restarts its timer, so
    events only shorten gaps. The p20 of the general estimate took those short gaps for the
    period: a companion's start sends three or four statuses within 0.3 s (link up, fix,
    optimiser ready), the gaps of 0.03 s made the status stream's period 0.03 s for the
    next 32 statuses (a minute), and every drone that had heard them planned a status every
    30 ms, 23 kB over the 3 s horizon, more than the window's budget: whichever drone's
    statuses came in a burst took the link from the others (the 2-drone fig. 7.3 test's red
    drone lost its precedence). A lost heartbeat of another agent doubles one gap; the 0.4
    keeps the jittered single periods beside it."""
    gaps = [b - a for a, b in itertools.pairwise(times) if b - a > 1e-9]
    if not gaps:
        return None
    longest = max(gaps)
    long_gaps = sorted(g for g in gaps if g >= 0.4 * longest)
    return long_gaps[len(long_gaps) // 2]


def _increasing(counts: list[int | None]) -> bool:
    """Every message carries a per-stream number and they increase (a restarted sender
    starts again from 0: then the numbers do not count the periods in between)."""
    return len(counts) >= 2 and all(a is not None and b is not None and b > a
                                    for a, b in itertools.pairwise(counts))


def _seq_paced(times: list[float], seqs: list[int]) -> bool:
    """Every gap spans the same time per sequence step (within 20 %, room for jitter)."""
    per_step = []
    for (t0, s0), (t1, s1) in itertools.pairwise(zip(times, seqs, strict=True)):
        if s1 <= s0:
            return False
        per_step.append((t1 - t0) / (s1 - s0))
    if not per_step:
        return False
    lo, hi = min(per_step), max(per_step)
    return hi > 0 and hi - lo <= 0.2 * hi


def _with_seq_time(message: Message, seq: int, t_gen: float) -> Message:
    """A copy of a validated message with another seq and (finite) t_gen, not re-validated:
    forecasts build tens of messages per decision (the hot path)."""
    copy = object.__new__(Message)
    for name in Message.__slots__:
        object.__setattr__(copy, name, getattr(message, name))
    object.__setattr__(copy, "seq", seq)
    object.__setattr__(copy, "t_gen", t_gen)
    return copy


def _with_data(message: Message, seq: int, t_gen: float, data: Any) -> Message:
    """:func:`_with_seq_time` carrying ``data`` of another validated message of the stream."""
    copy = _with_seq_time(message, seq, t_gen)
    object.__setattr__(copy, "data", data)
    return copy


def _best_size(message: Message) -> int:
    return message.versions[0].size if message.versions else message.size


def _scaled_versions(last: Message, best_size: int) -> tuple[Version, ...]:
    if not last.versions:
        return ()
    full = last.versions[0].size
    factor = best_size / full if full > 0 else 1.0
    return tuple(
        Version(name=v.name, size=round(v.size * factor), quality=v.quality) for v in last.versions
    )


class LatencyEstimator:
    """One-way latency (t_rcv - t_sent) over the last ``window`` samples.

    ``mean_s`` (the thesis plans with the average observed latency, ch. 5.3) places planned
    receptions; ``high_s`` (a high percentile) bounds how old a message may be and still be in
    flight. One slow sample moves neither much, unlike the last sample alone.
    """

    __slots__ = ("_default_s", "_samples", "quantile")

    def __init__(self, *, default_s: float, window: int = 64, quantile: float = 0.95) -> None:
        if not default_s >= 0:
            raise ValueError(f"default_s must be >= 0, got {default_s}")
        self._default_s = default_s
        self._samples: deque[float] = deque(maxlen=window)
        self.quantile = quantile

    def update(self, latency_s: float) -> LatencyEstimator:
        if math.isfinite(latency_s) and latency_s >= 0:
            self._samples.append(latency_s)
        return self

    def __len__(self) -> int:
        return len(self._samples)

    @property
    def mean_s(self) -> float:
        if not self._samples:
            return self._default_s
        return sum(self._samples) / len(self._samples)

    @property
    def high_s(self) -> float:
        if not self._samples:
            return 2.0 * self._default_s
        ordered = sorted(self._samples)
        return ordered[min(len(ordered) - 1, int(self.quantile * len(ordered)))]

    def as_dict(self) -> dict[str, Any]:
        return {"mean_s": self.mean_s, "high_s": self.high_s, "samples": len(self)}
