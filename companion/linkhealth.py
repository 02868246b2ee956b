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
    _n_settled: int = 0
    _lost: OrderedDict[int, int] = field(default_factory=OrderedDict)
    """Seq -> settle number of the messages counted lost that are still in the window."""

    def on_sent(self, seq: int, now: float) -> None:
        self._pending[seq] = now
        while len(self._pending) > self.max_pending:
            lost, _ = self._pending.popitem(last=False)
            self._settle(False, lost)

    def on_delivered(self, seq: int) -> None:
        """A report names ``seq``. One later than ``grace_s`` (this drone stalled, or the
        station did, with the reports waiting in a buffer) undoes its loss: a companion
        stopped 4 s showed the messages of its last 3 s as lost on the dashboard."""
        if self._pending.pop(seq, None) is not None:
            self._settle(True, seq)
            return
        number = self._lost.pop(seq, None)
        first_kept = self._n_settled - len(self._settled)
        if number is not None and number >= first_kept:
            self._settled[number - first_kept] = True

    def _settle(self, delivered: bool, seq: int) -> None:
        if not delivered:
            self._lost[seq] = self._n_settled
        self._n_settled += 1
        self._settled.append(delivered)
        del self._settled[:-self.window]
        while self._lost and next(iter(self._lost.values())) < self._n_settled - self.window:
            self._lost.popitem(last=False)

    def loss(self, now: float) -> float | None:
        """Share of the last settled messages that were lost; None before any settled."""
        while self._pending:
            seq, t_sent = next(iter(self._pending.items()))
            if now - t_sent < self.grace_s:
                break
            del self._pending[seq]
            self._settle(False, seq)
        if not self._settled:
            return None
        return self._settled.count(False) / len(self._settled)

    @staticmethod
    def delta_s(constraint: Any) -> float | None:
        """Queueing delay of the constraint's last window (s), when it keeps link stats."""
        stats = getattr(constraint, "last_stats", None)
        delay = getattr(stats, "queueing_delay_s", None)
        return None if delay is None else max(0.0, float(delay))
