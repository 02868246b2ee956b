"""Receiver reports (ground -> every drone): what arrived and clock echoes (ARCHITECTURE.md).

Sans-I/O. Every ``interval_s`` the station reports the messages it received since the last
report; each entry is repeated in ``repeat`` consecutive reports so one lost report does not
hide a delivery from the drones' optimisers (utility is counted at the receiver, ch. 4).
Per drone it echoes the t_sent of that drone's latest datagram and our t_rcv of it, which
with the report's own send time gives NTP-style round trip and clock offset estimates.

Echo state scales with the fleet, not with every id ever heard: a sender silent for
``echo_ttl_s`` is forgotten, at most ``max_senders`` are kept (the least recently heard go
first), and one report carries at most ``max_echoes`` echoes, those echoed least recently,
so with more senders the echoes rotate and every drone still gets one every few reports.
"""

from __future__ import annotations

import heapq
from collections import OrderedDict, deque
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

from companion.protocol.errors import LocalProtocolError
from companion.protocol.records import ClockEcho, Report, ReportEntry, entry_from_message
from companion.protocol.wire import dumps_json
from utility_specs.message import Message

__all__ = ["MAX_ENTRY_DATA_BYTES", "ReportScheduler"]

MAX_ENTRY_DATA_BYTES = 512
"""Largest entry ``data`` (JSON bytes) reported; with the entry's other fields (at most
~550 bytes, ids full of escaped characters included) it always fits one report datagram."""


def _small(data: Mapping[str, Any]) -> bool:
    try:
        return len(dumps_json(dict(data), "entry data")) <= MAX_ENTRY_DATA_BYTES
    except LocalProtocolError:
        return False


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
    max_echoes
        Most clock echoes in one report (they rotate beyond that).
    echo_ttl_s
        A sender not heard for this long gets no more echoes and is forgotten.
    max_senders
        Most senders whose latest clock pair is kept.
    """

    def __init__(
        self,
        *,
        interval_s: float,
        repeat: int = 2,
        max_entries: int = 4096,
        max_echoes: int = 32,
        echo_ttl_s: float = 10.0,
        max_senders: int = 1024,
        now: float,
    ) -> None:
        if not interval_s > 0 or repeat < 1 or max_entries < 1:
            raise ValueError("interval_s must be > 0, repeat and max_entries >= 1")
        if max_echoes < 1 or max_senders < 1 or not echo_ttl_s > 0:
            raise ValueError("max_echoes and max_senders must be >= 1, echo_ttl_s > 0")
        self.interval_s = interval_s
        self.repeat = repeat
        self.max_echoes = max_echoes
        self.echo_ttl_s = echo_ttl_s
        self.max_senders = max_senders
        self._pending: deque[_Pending] = deque(maxlen=max_entries)
        self._echoes: OrderedDict[str, ClockEcho] = OrderedDict()
        """Latest clock pair per sender, least recently heard first."""
        self._echoed_in: dict[str, int] = {}
        """Sender -> number of the report that last carried its echo."""
        self._next = now + interval_s
        self.reports_built = 0
        self.entries_trimmed = 0
        """Entries whose data was too large to report (sent without it)."""

    def on_message(self, message: Message, *, t_rcv: float) -> None:
        entry = entry_from_message(message, t_rcv=t_rcv)
        if entry.data and not _small(entry.data):
            # Metadata that fits a DATA fragment may not fit a report entry: reported
            # without its data rather than blocking every report while it is pending.
            entry = replace(entry, data={})
            self.entries_trimmed += 1
        self._pending.append(_Pending(entry, self.repeat))

    def on_datagram(self, sender: str, *, t_sent: float, t_rcv: float) -> None:
        """Remember the newest (t_sent, t_rcv) pair of ``sender`` for the clock echo."""
        old = self._echoes.get(sender)
        if old is None or t_sent >= old.t_sent:
            self._echoes[sender] = ClockEcho(sender=sender, t_sent=t_sent, t_rcv=t_rcv)
            self._echoes.move_to_end(sender)
            while len(self._echoes) > self.max_senders:
                self._forget(next(iter(self._echoes)))

    @property
    def sender_count(self) -> int:
        """Senders with a clock pair kept."""
        return len(self._echoes)

    def _forget(self, sender: str) -> None:
        del self._echoes[sender]
        self._echoed_in.pop(sender, None)

    def _take_echoes(self, now: float) -> tuple[ClockEcho, ...]:
        """Forget senders silent for ``echo_ttl_s``; the ``max_echoes`` echoed least
        recently (never echoed first) go into this report."""
        while self._echoes:
            sender, oldest = next(iter(self._echoes.items()))
            if now - oldest.t_rcv <= self.echo_ttl_s:
                break
            self._forget(sender)
        chosen = list(self._echoes)
        if len(chosen) > self.max_echoes:
            chosen = heapq.nsmallest(
                self.max_echoes, chosen, key=lambda s: self._echoed_in.get(s, -1)
            )
        for sender in chosen:
            self._echoed_in[sender] = self.reports_built
        return tuple(self._echoes[s] for s in chosen)

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
        echoes = self._take_echoes(now)
        self.reports_built += 1
        return Report(entries=entries, echoes=echoes)
