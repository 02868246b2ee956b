"""The goodput constraint interface shared by the optimiser and the constraint strategies.

The optimiser (ch. 5, eq. 5.5/5.7) prunes every plan whose sent bytes exceed
``limit_bytes_per_s(now) * window_s`` in any window of length ``window_s``. A strategy
decides that limit: a constant, the adaptive SGD model of ch. 6 (eq. 6.7/6.8), or AIMD
(algorithm 4). Time always comes in as ``now`` (fleet clock, seconds); nothing here reads a
clock.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from companion.middleware.linkstats import RoundTrip

__all__ = ["ConstantConstraint", "GoodputConstraint", "LinkSample"]


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


class GoodputConstraint(ABC):
    """ξ: how many bytes per second the application may send, averaged over ``window_s``."""

    window_s: float

    def __init__(self, *, window_s: float) -> None:
        if not window_s > 0:
            raise ValueError(f"window_s must be > 0, got {window_s}")
        self.window_s = window_s
        self._sent: deque[tuple[float, int]] = deque()
        self._sent_bytes = 0

    @abstractmethod
    def limit_bytes_per_s(self, *, now: float) -> float:
        """ξ(now) in bytes per second."""

    def budget_bytes(self, *, now: float) -> float:
        """Bytes that may be sent in one window of length ``window_s`` (ξ·T)."""
        return self.limit_bytes_per_s(now=now) * self.window_s

    def on_sample(self, sample: LinkSample, *, now: float) -> None:  # noqa: B027
        """Learn from one delivered message (default: nothing to learn)."""

    def on_samples(self, samples: Iterable[LinkSample], *, now: float) -> None:
        """Learn from all messages of one receiver report (default: one by one)."""
        for sample in samples:
            self.on_sample(sample, now=now)

    def on_round_trip(self, round_trip: RoundTrip, *, now: float) -> None:  # noqa: B027
        """A report round trip (clock offset and delay); default: not used."""

    def on_sent(self, size_bytes: int, *, now: float) -> None:
        """Record that ``size_bytes`` went on the link at ``now``."""
        self._sent.append((now, size_bytes))
        self._sent_bytes += size_bytes
        self._forget_before(now - self.window_s)  # bounded even when nobody asks

    def sent_in_window(self, *, now: float) -> int:
        """Bytes recorded by :meth:`on_sent` in (now - window_s, now]."""
        self._forget_before(now - self.window_s)
        return self._sent_bytes

    def _forget_before(self, horizon: float) -> None:
        while self._sent and self._sent[0][0] <= horizon:
            self._sent_bytes -= self._sent.popleft()[1]

    def admits(self, size_bytes: int, *, now: float) -> bool:
        """Whether sending ``size_bytes`` now keeps the last window within budget."""
        return self.sent_in_window(now=now) + size_bytes <= self.budget_bytes(now=now)


class ConstantConstraint(GoodputConstraint):
    """A fixed ξ (eq. 5.7 with a constant A)."""

    def __init__(self, *, limit_bytes_per_s: float, window_s: float = 2.5) -> None:
        super().__init__(window_s=window_s)
        if not limit_bytes_per_s >= 0:
            raise ValueError(f"limit_bytes_per_s must be >= 0, got {limit_bytes_per_s}")
        self._limit = float(limit_bytes_per_s)

    def limit_bytes_per_s(self, *, now: float) -> float:
        return self._limit
