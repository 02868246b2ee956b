"""A token bucket on the link's own terms: bytes earned at a rate up to a burst, paid per
datagram including its IP/UDP header. The companion's pacer and the SITL's shaped relay
(a radio's queue) both drain a FIFO through one; sans-I/O, time is an argument.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["UDP_IP_OVERHEAD_BYTES", "TokenBucket"]

UDP_IP_OVERHEAD_BYTES = 28
"""IPv4 + UDP header bytes a datagram costs on the link besides its payload."""


@dataclass(slots=True)
class TokenBucket:
    """``rate_bytes_per_s`` earned up to ``burst_bytes``, full at the start. A datagram
    larger than the burst leaves once the bucket is full and leaves a debt, so any size
    goes at the rate on average."""

    rate_bytes_per_s: float
    burst_bytes: int
    tokens: float = -1.0
    t: float | None = None
    """The time the tokens are counted at (None: not yet used)."""

    def __post_init__(self) -> None:
        self.tokens = float(self.burst_bytes)

    def refill(self, now: float) -> None:
        """Count the tokens earned up to ``now`` (never backwards)."""
        if self.t is not None and now > self.t:
            self.tokens = min(float(self.burst_bytes),
                              self.tokens + (now - self.t) * self.rate_bytes_per_s)
        if self.t is None or now > self.t:
            self.t = now

    def due(self, cost: int, *, ahead: float = 0.0, idle_t: float = 0.0) -> float:
        """When a datagram of ``cost`` may leave after ``ahead`` bytes still to pay for
        (``idle_t`` if the bucket was never used)."""
        t = self.t if self.t is not None else idle_t
        missing = ahead + min(cost, self.burst_bytes) - self.tokens
        return t if missing <= 0 else t + missing / self.rate_bytes_per_s

    def take(self, cost: int, at: float) -> None:
        """A datagram of ``cost`` leaves at ``at`` (its :meth:`due` time)."""
        self.refill(at)
        self.tokens -= cost
