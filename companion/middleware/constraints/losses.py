"""Which of this agent's messages the link lost, from its sends and the receiver reports.

Eq. 6.4 reads congestion from latency only. On a link whose queue is small next to one
message (the demo's relay: a 20 kB queue, 7-30 kB camera frames) a burst of several
drones' frames overflows the queue before the latency of any reported message has shown
it: the lost frames are never reported, so they never count. A loss is the congestion
signal every transport protocol reads; :class:`SendLedger` finds them.

The link is a FIFO (the radio's queue, the relay's, the pacer's), so this agent's messages
arrive in the order it sent them. A delivered message is matched to the oldest unmatched
send of its size among the next ``horizon`` sends; the sends before it that were not
delivered are lost. A delivered message with no matching send (sent before the ledger was
made, or a message the ledger never saw) matches nothing and loses nothing.

Sans-I/O: sizes and times come in as arguments.
"""

from __future__ import annotations

import itertools
from collections import deque
from dataclasses import dataclass, field

__all__ = ["SendLedger"]


@dataclass(slots=True)
class SendLedger:
    """This agent's sends (time, size) not yet matched by a delivery, oldest first."""

    horizon: int = 64
    """How many unmatched sends a delivery is searched among."""
    max_records: int = 1024
    """Unmatched sends kept; older ones are dropped (not counted lost: a link that reports
    nothing at all is told by the silence, not by this ledger)."""
    counters: dict[str, int] = field(
        default_factory=lambda: dict.fromkeys(("sent", "delivered", "lost", "unmatched"), 0))
    _records: deque[tuple[float, int]] = field(default_factory=deque)

    def on_sent(self, size_bytes: int, *, now: float) -> None:
        """This agent put a message of ``size_bytes`` on the link at ``now``."""
        self.counters["sent"] += 1
        self._records.append((now, size_bytes))
        while len(self._records) > self.max_records:
            self._records.popleft()

    def on_delivered(self, size_bytes: int) -> int:
        """A report listed one more of this agent's messages (each once, in send order):
        how many earlier sends it shows were lost."""
        for i, (_, size) in enumerate(itertools.islice(self._records, self.horizon)):
            if size == size_bytes:
                for _ in range(i + 1):
                    self._records.popleft()
                self.counters["delivered"] += 1
                self.counters["lost"] += i
                return i
        self.counters["unmatched"] += 1
        return 0

    def forget(self, t_from: float, t_to: float) -> None:
        """Drop the sends made in [t_from, t_to]: the agent stalled then, so one of them lost
        (an image half sent when it stopped) is its own doing, not the link's congestion."""
        self._records = deque(r for r in self._records if not t_from <= r[0] <= t_to)

    def __len__(self) -> int:
        return len(self._records)
