"""Pacing: the datagrams of a message leave at a bounded rate, not in one burst.

A 30 kB image is 25 datagrams. Handed to the socket in one loop they reach the radio's queue
within a millisecond; two drones whose frame clocks happen to line up then offer twice that at
once, and a bottleneck queue of a few tens of kB drops the tail of both images (the
``--netns`` tbf queue and the demo's relay did, 32 and 115-154 datagrams per run). The
constraint (thesis ch. 6) bounds bytes per window, not the instantaneous burst; the pacer
bounds the burst: a token bucket of ``rate_bytes_per_s`` and ``burst_bytes`` in front of a
FIFO of whole units. The rate is the radio's own (``[ground_station] link_rate_bytes_per_s``):
a message then waits in the pacer no longer than it would have waited in the radio's queue
had it been alone there, so the delay the adaptive constraint measures is the link's, not
the pacer's. (Pacing at 4ξ, below the link's rate when ξ is small, was tried first: the
pacer's own wait read as queueing delay, ξ fell, the pacing slowed, and the demo delivered
a fifth fewer images.)

A unit (all datagrams of one message) is queued whole or not at all: when the backlog cannot
take all of it, the whole unit is dropped and counted, never half-queued (a message missing
one fragment is lost anyway, and its other fragments would waste the link).

Sans-I/O: time is an argument; the shell (``companion.transport``) owns the socket and one
timer for :meth:`Pacer.next_due`.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Generic, TypeVar

from companion.protocol.bucket import UDP_IP_OVERHEAD_BYTES, TokenBucket

__all__ = ["UDP_IP_OVERHEAD_BYTES", "Pacer"]

A = TypeVar("A")


@dataclass(slots=True)
class Pacer(Generic[A]):
    """Token bucket (``rate_bytes_per_s``, ``burst_bytes``) in front of a FIFO of at most
    ``max_backlog_bytes``; each datagram costs its size + ``overhead_bytes``.

    ``offer`` queues a unit whole or drops it whole: when the backlog cannot take all of it,
    or when what is queued before it still needs more than ``max_delay_s`` (what it carries
    would arrive too late, and the link is over-offered). ``pop_due`` returns what the bucket
    pays for by ``now``, in order; ``next_due`` says when the head may leave.
    """

    rate_bytes_per_s: float
    burst_bytes: int = 3_000
    max_backlog_bytes: int = 256 * 1024
    overhead_bytes: int = UDP_IP_OVERHEAD_BYTES
    max_delay_s: float = 1.0
    counters: dict[str, int] = field(default_factory=lambda: dict.fromkeys(
        ("units_queued", "units_dropped", "datagrams_released", "bytes_released"), 0))
    max_backlog_seen_bytes: int = 0
    _queue: deque[tuple[bytes, A, int]] = field(default_factory=deque)
    _backlog: int = 0
    _bucket: TokenBucket = field(init=False)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.rate_bytes_per_s) and self.rate_bytes_per_s > 0):
            raise ValueError(f"pacer: rate must be a finite number > 0, got "
                             f"{self.rate_bytes_per_s!r}")
        if not (self.burst_bytes > 0 and self.max_backlog_bytes > 0 and self.overhead_bytes >= 0
                and self.max_delay_s > 0):
            raise ValueError("pacer: burst, backlog and delay must be > 0, overhead >= 0")
        self._bucket = TokenBucket(self.rate_bytes_per_s, self.burst_bytes)

    @property
    def backlog_bytes(self) -> int:
        """Bytes (overhead included) queued and not yet released."""
        return self._backlog

    def __len__(self) -> int:
        return len(self._queue)

    def offer(self, datagrams: Sequence[bytes], to: A, now: float) -> bool:
        """Queue all ``datagrams`` (one unit) for ``to``; False, and nothing queued, when the
        backlog cannot take all of them or is busy for longer than ``max_delay_s``."""
        cost = sum(len(d) + self.overhead_bytes for d in datagrams)
        if self._backlog + cost > self.max_backlog_bytes \
                or (self._queue and self.idle_at(now) - now > self.max_delay_s):
            self.counters["units_dropped"] += 1
            return False
        if not self._queue:  # the bucket filled while idle; a waiting queue keeps its own time
            self._bucket.refill(now)
        for data in datagrams:
            self._queue.append((data, to, len(data) + self.overhead_bytes))
        self._backlog += cost
        self.max_backlog_seen_bytes = max(self.max_backlog_seen_bytes, self._backlog)
        self.counters["units_queued"] += 1
        return True

    def pop_due(self, now: float) -> list[tuple[bytes, A]]:
        """The datagrams whose turn has come by ``now``, oldest first."""
        out: list[tuple[bytes, A]] = []
        while self._queue:
            due = self._head_due()
            if due is None or due > now:
                break
            data, to, cost = self._queue.popleft()
            self._bucket.take(cost, due)
            self._backlog -= cost
            self.counters["datagrams_released"] += 1
            self.counters["bytes_released"] += len(data)
            out.append((data, to))
        self._bucket.refill(now)
        return out

    def next_due(self) -> float | None:
        """When the head of the queue may leave; None when nothing waits."""
        return self._head_due()

    def idle_at(self, now: float) -> float:
        """When everything queued now will have left (``now`` when nothing waits)."""
        if not self._queue:
            return now
        self._bucket.refill(now)
        last = self._queue[-1][2]
        # the last datagram leaves once the bucket has paid for all before it
        return max(now, self._bucket.due(last, ahead=self._backlog - last, idle_t=now))

    def _head_due(self) -> float | None:
        return self._bucket.due(self._queue[0][2]) if self._queue else None
