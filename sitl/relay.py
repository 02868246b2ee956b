"""A shaped bottleneck in user space: token bucket, byte-bounded FIFO, background load.

The demo's link when there is no root for network namespaces (``uav-sitl fleet`` runs it
between the drones and the ground station, :mod:`sitl.relay_udp` is the socket shell). It
behaves like ``tc tbf`` on the shared medium of ``--netns``: datagrams leave at most at
``rate`` bytes/s (plus a ``burst``), wait in one FIFO shared by every drone while the bucket
is empty, and are dropped when the queue holds ``queue_limit_bytes``. So a fleet that offers
more than the link carries sees queueing delay first, then loss: what the adaptive
constraint (thesis ch. 6) reads from the receiver reports. An optional background load
(thesis fig. 7.4: cross traffic switched on mid-mission) takes its share of the same queue.

Sans-I/O: time is an argument; the shell owns the sockets, the clock and one timer.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Generic, TypeVar

from companion.protocol.bucket import UDP_IP_OVERHEAD_BYTES, TokenBucket

__all__ = ["UDP_IP_OVERHEAD_BYTES", "BackgroundLoad", "ShapedQueue"]

T = TypeVar("T")


@dataclass(frozen=True, slots=True)
class BackgroundLoad:
    """Cross traffic of ``rate_bytes_per_s`` in ``packet_bytes`` packets, from ``start_s`` for
    ``duration_s`` (None: to the end), times relative to the origin the shell sets."""

    rate_bytes_per_s: float
    start_s: float = 0.0
    duration_s: float | None = None
    packet_bytes: int = 1200

    def __post_init__(self) -> None:
        if not (self.rate_bytes_per_s > 0 and self.start_s >= 0 and self.packet_bytes > 0):
            raise ValueError("background: rate and packet size must be > 0, start >= 0")
        if self.duration_s is not None and not self.duration_s > 0:
            raise ValueError("background: duration must be > 0")

    def time_of(self, n: int) -> float | None:
        """Origin-relative send time of packet ``n`` (0, 1, ...), None past the end."""
        at = self.start_s + n * self.packet_bytes / self.rate_bytes_per_s
        end = math.inf if self.duration_s is None else self.start_s + self.duration_s
        return at if at < end else None


@dataclass(slots=True)
class ShapedQueue(Generic[T]):
    """Token bucket of ``rate_bytes_per_s`` and ``burst_bytes`` in front of a FIFO holding at
    most ``queue_limit_bytes`` (each datagram costs its size + ``overhead_bytes``).

    ``offer`` enqueues or drops (tail drop, as tbf); ``pop_due`` releases what the bucket
    pays for by ``now``; ``next_due`` says when the head can go. Items are opaque: the shell
    passes (datagram, address), the background load passes None.
    """

    rate_bytes_per_s: float
    queue_limit_bytes: int
    burst_bytes: int = 3000
    overhead_bytes: int = UDP_IP_OVERHEAD_BYTES
    background: BackgroundLoad | None = None
    origin: float | None = None
    """When the background's clock starts (the mission start); None: not yet."""
    counters: dict[str, int] = field(default_factory=lambda: dict.fromkeys(
        ("sent_packets", "sent_bytes", "dropped_packets", "dropped_bytes",
         "background_sent_packets", "background_dropped_packets"), 0))
    max_backlog_bytes: int = 0
    _queue: deque[tuple[int, T | None]] = field(default_factory=deque)
    _backlog: int = 0
    _bucket: TokenBucket = field(init=False)
    _background_offered: int = 0
    _out: list[T] = field(default_factory=list)

    def __post_init__(self) -> None:
        if not (self.rate_bytes_per_s > 0 and self.queue_limit_bytes > 0
                and self.burst_bytes > 0 and self.overhead_bytes >= 0):
            raise ValueError("rate, queue limit and burst must be > 0")
        self._bucket = TokenBucket(self.rate_bytes_per_s, self.burst_bytes)

    @property
    def backlog_bytes(self) -> int:
        return self._backlog

    def __len__(self) -> int:
        return len(self._queue)

    def _enqueue(self, size: int, item: T | None) -> bool:
        cost = size + self.overhead_bytes
        if self._backlog + cost > self.queue_limit_bytes:
            return False
        self._queue.append((cost, item))
        self._backlog += cost
        self.max_backlog_bytes = max(self.max_backlog_bytes, self._backlog)
        return True

    def _offer_background(self, now: float) -> None:
        if self.background is None or self.origin is None:
            return
        while (t := self._next_background()) is not None and t <= now:
            self._background_offered += 1
            if not self._enqueue(self.background.packet_bytes, None):
                self.counters["background_dropped_packets"] += 1

    def offer(self, item: T, size: int, now: float) -> bool:
        """Queue one datagram of ``size`` payload bytes; False when the queue is full."""
        self._release_until(now)  # what left before now frees its room first
        if self._enqueue(size, item):
            return True
        self.counters["dropped_packets"] += 1
        self.counters["dropped_bytes"] += size
        return False

    def _release_until(self, now: float) -> None:
        """Serve the FIFO in time order up to ``now``: each head leaves the moment the
        bucket holds its cost; background packets join at their own times. What leaves
        waits in the outbox for :meth:`pop_due`."""
        out = self._out
        while True:
            t_head = self._head_time()
            t_bg = self._next_background()
            if t_bg is not None and t_bg <= now and (t_head is None or t_bg < t_head):
                self._bucket.refill(t_bg)
                self._offer_background(t_bg)
                continue
            if t_head is None or t_head > now:
                break
            cost, item = self._queue.popleft()
            self._bucket.take(cost, t_head)
            self._backlog -= cost
            if item is None:
                self.counters["background_sent_packets"] += 1
            else:
                self.counters["sent_packets"] += 1
                self.counters["sent_bytes"] += cost - self.overhead_bytes
                out.append(item)
        self._bucket.refill(now)
        self._offer_background(now)

    def _head_time(self) -> float | None:
        return self._bucket.due(self._queue[0][0]) if self._queue else None

    def _next_background(self) -> float | None:
        if self.background is None or self.origin is None:
            return None
        at = self.background.time_of(self._background_offered)
        return None if at is None else self.origin + at

    def pop_due(self, now: float) -> list[T]:
        """The datagrams that leave the link by ``now``, in order."""
        self._release_until(now)
        out, self._out = self._out, []
        return out

    def next_due(self) -> float | None:
        """When the next thing happens (a departure or a background packet), or None
        (``now`` or earlier while the outbox holds datagrams: pop them)."""
        if self._out:
            return self._bucket.t
        times = [t for t in (self._head_time(), self._next_background()) if t is not None]
        return min(times) if times else None

    def start_background(self, now: float) -> None:
        """Set the background's origin (the mission start); once."""
        if self.origin is None:
            self._release_until(now)
            self.origin = now
