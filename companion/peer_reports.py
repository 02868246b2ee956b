"""This drone as a receiver on the shared medium: the report of what it heard from peers.

Sans-I/O (docs/peers.md). :meth:`PeerReporter.on_message` collects each peer message heard
(an entry, and the sender's clock pair as the ground station keeps it); :meth:`take` returns
the report of everything since the previous one, in the ground station's format, so every
sender learns what this drone holds (its optimiser plans with it, its goodput constraint
learns the medium's latency from it). This drone's own optimiser learns each delivery at
once (``receiver`` = this drone, companion/peers.py), not a report period later.
"""

from __future__ import annotations

from companion.protocol.records import ClockEcho, Report, ReportEntry, entry_from_message
from utility_specs.message import Message

__all__ = ["MAX_REPORT_ENTRIES", "REPORT_INTERVAL_S", "PeerReporter"]

REPORT_INTERVAL_S = 0.25
"""A companion reports what it heard from peers this often (the ground station's default)."""
MAX_REPORT_ENTRIES = 256
"""Entries held between two reports; beyond, the oldest are dropped (counted)."""


class PeerReporter:
    """What this drone heard from peers since its last report (module docstring)."""

    def __init__(self, own_id: str, *, max_entries: int = MAX_REPORT_ENTRIES) -> None:
        self.own_id = own_id
        self.max_entries = max_entries
        self._entries: list[ReportEntry] = []
        self._echoes: dict[str, ClockEcho] = {}
        self.counters: dict[str, int] = {"heard": 0, "reports": 0, "entries_dropped": 0}

    def on_message(self, message: Message, *, t_rcv: float) -> ReportEntry | None:
        """Collect ``message`` for the next report; returns its entry (None: not reported,
        our own or one the report format cannot carry)."""
        if message.sender == self.own_id:
            return None
        try:
            entry = entry_from_message(message, t_rcv=t_rcv)
        except ValueError:  # a message the report format cannot carry: not reported
            return None
        self.counters["heard"] += 1
        self._entries.append(entry)
        if len(self._entries) > self.max_entries:
            del self._entries[0]
            self.counters["entries_dropped"] += 1
        if message.t_sent is not None:
            self._echoes[message.sender] = ClockEcho(sender=message.sender,
                                                     t_sent=message.t_sent, t_rcv=t_rcv)
        return entry

    def take(self) -> Report | None:
        """The report since the previous one; None when nothing was heard."""
        if not self._entries and not self._echoes:
            return None
        report = Report(entries=tuple(self._entries), echoes=tuple(self._echoes.values()))
        self._entries = []
        self._echoes = {}
        self.counters["reports"] += 1
        return report
