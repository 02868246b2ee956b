"""What the drone tells the station about its own link: queueing delay Δ and loss.

Sans-I/O. The loss is the share of this drone's sent messages that no receiver report
mentioned within ``grace_s`` (reports repeat each entry, so one lost report does not count
as a loss); Δ is the constraint's last window's mean latency above the base latency
(thesis ch. 6: it rises when a queue builds). Both go into the status the drone sends.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any

__all__ = ["LinkHealth"]


@dataclass(slots=True)
class LinkHealth:
    grace_s: float = 3.0
    """A sent message unreported this long after its send is counted lost."""
    window: int = 100
    """Loss is over the last ``window`` settled messages."""
    max_pending: int = 5000
    _pending: OrderedDict[int, float] = field(default_factory=OrderedDict)
    _settled: list[bool] = field(default_factory=list)
    """True: delivered, False: lost; the newest last."""

    def on_sent(self, seq: int, now: float) -> None:
        self._pending[seq] = now
        while len(self._pending) > self.max_pending:
            self._pending.popitem(last=False)
            self._settle(False)

    def on_delivered(self, seq: int) -> None:
        if self._pending.pop(seq, None) is not None:
            self._settle(True)

    def _settle(self, delivered: bool) -> None:
        self._settled.append(delivered)
        del self._settled[:-self.window]

    def loss(self, now: float) -> float | None:
        """Share of the last settled messages that were lost; None before any settled."""
        while self._pending:
            seq, t_sent = next(iter(self._pending.items()))
            if now - t_sent < self.grace_s:
                break
            del self._pending[seq]
            self._settle(False)
        if not self._settled:
            return None
        return self._settled.count(False) / len(self._settled)

    @staticmethod
    def delta_s(constraint: Any) -> float | None:
        """Queueing delay of the constraint's last window (s), when it keeps link stats."""
        stats = getattr(constraint, "last_stats", None)
        delay = getattr(stats, "queueing_delay_s", None)
        return None if delay is None else max(0.0, float(delay))
