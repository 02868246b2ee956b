"""Receiver reports (ground -> every drone): what arrived and clock echoes (ARCHITECTURE.md).

Sans-I/O. Every ``interval_s`` the station reports the messages it received since the last
report; each entry is repeated in ``repeat`` consecutive reports so one lost report does not
hide a delivery from the drones' optimisers (utility is counted at the receiver, ch. 4).
Per drone it echoes the t_sent of that drone's latest datagram and our t_rcv of it, which
with the report's own send time gives NTP-style round trip and clock offset estimates.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from companion.protocol.records import ClockEcho, Report, ReportEntry, entry_from_message
from utility_specs.message import Message

__all__ = ["ReportScheduler"]


@dataclass(slots=True)
class _Pending:
    entry: ReportEntry
    remaining: int


class ReportScheduler:
    """Collects deliveries and clock echoes; :meth:`due` yields a report each interval.

    Parameters
    ----------
    interval_s
        Report period (a few per second, so the adaptive constraint gets fresh samples).
    repeat
        In how many consecutive reports each entry appears.
    max_entries
        Bound on entries held (the oldest are dropped first under overload).
    """

    def __init__(
        self, *, interval_s: float, repeat: int = 2, max_entries: int = 4096, now: float
    ) -> None:
        if not interval_s > 0 or repeat < 1 or max_entries < 1:
            raise ValueError("interval_s must be > 0, repeat and max_entries >= 1")
        self.interval_s = interval_s
        self.repeat = repeat
        self._pending: deque[_Pending] = deque(maxlen=max_entries)
        self._echoes: dict[str, ClockEcho] = {}
        self._next = now + interval_s
        self.reports_built = 0

    def on_message(self, message: Message, *, t_rcv: float) -> None:
        self._pending.append(_Pending(entry_from_message(message, t_rcv=t_rcv), self.repeat))

    def on_datagram(self, sender: str, *, t_sent: float, t_rcv: float) -> None:
        """Remember the newest (t_sent, t_rcv) pair of ``sender`` for the clock echo."""
        old = self._echoes.get(sender)
        if old is None or t_sent >= old.t_sent:
            self._echoes[sender] = ClockEcho(sender=sender, t_sent=t_sent, t_rcv=t_rcv)

    def get_timer(self) -> float:
        return self._next

    def due(self, *, now: float) -> Report | None:
        """The report to send now, or None before the next report time."""
        if now < self._next:
            return None
        # Skip missed periods instead of bursting to catch up.
        periods = int((now - self._next) // self.interval_s) + 1
        self._next += periods * self.interval_s
        entries = tuple(p.entry for p in self._pending)
        for pending in self._pending:
            pending.remaining -= 1
        while self._pending and self._pending[0].remaining <= 0:
            self._pending.popleft()
        self._pending = deque(
            (p for p in self._pending if p.remaining > 0), maxlen=self._pending.maxlen
        )
        echoes = tuple(self._echoes.values())
        self.reports_built += 1
        return Report(entries=entries, echoes=echoes)
