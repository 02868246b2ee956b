"""Receiver reports on the shared medium use air time: the goodput budget counts them.

Every drone on a medium puts a receiver report there every 0.25 s (companion/peer_reports.py);
with four drones that is 16 datagrams a second the optimiser never decided. The thesis' goodput
constraint counts every message of the middleware in the window (eq. 6.2: the sum over all
messages exchanged), so the reports' bytes must come off what the plan may send.

:class:`ReportTraffic` keeps (send time, wire bytes) of the reports this drone sent and the
peers' reports it heard; :class:`CountingReports` wraps the decider's goodput constraint and
takes the reports of the last window T off its budget ξ·T. Reports recur at a fixed period,
so what they used in the last window is what they will use in each window of the plan: the
root window is exact, later windows assume the same report traffic. ξ itself (the status
message's figure, the adaptive model) is the wrapped constraint's, unchanged. Sans-I/O: time
is an argument; the lock only guards the record shared between the event loop (which adds
reports) and the optimiser's thread (which reads the budget).
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Iterable, Mapping
from functools import lru_cache
from typing import Any

from companion.middleware.constraints.base import GoodputConstraint
from companion.middleware.constraints.linkstats import LinkSample, RoundTrip
from companion.protocol import Encoder
from companion.protocol.records import Report

__all__ = ["CountingReports", "ReportTraffic", "report_wire_bytes"]

_SIZING_KEY = bytes(32)
"""The key does not change a datagram's size (the tag has a fixed length)."""


@lru_cache(maxsize=64)
def _sizing_encoder(sender: str) -> Encoder:
    return Encoder(0, sender, _SIZING_KEY)


def report_wire_bytes(report: Report, *, sender: str) -> int:
    """Bytes on the medium of ``report`` sent by ``sender``: every datagram it encodes to
    (header, tag and body; the fleet id and packet number have fixed sizes)."""
    return sum(len(d) for d in _sizing_encoder(sender).encode_report(report, 0.0))


class ReportTraffic:
    """(send time, bytes) of the receiver reports on the medium, for one window back."""

    def __init__(self, *, keep_s: float = 10.0) -> None:
        self.keep_s = keep_s
        self._reports: deque[tuple[float, int]] = deque()
        self._lock = threading.Lock()
        self.counters: dict[str, int] = {"reports": 0, "bytes": 0}

    def add(self, t_sent: float, nbytes: int) -> None:
        with self._lock:
            self._reports.append((t_sent, nbytes))
            self.counters["reports"] += 1
            self.counters["bytes"] += nbytes
            while self._reports and self._reports[0][0] < t_sent - self.keep_s:
                self._reports.popleft()

    def bytes_in_window(self, *, now: float, window_s: float) -> int:
        """Bytes of the reports sent in [now - window_s, now] (a report at ``now`` counts,
        as a send at ``now`` does in the optimiser's windows)."""
        lo = now - window_s - 1e-9
        with self._lock:
            return sum(b for t, b in self._reports if lo <= t <= now + 1e-9)


class CountingReports(GoodputConstraint):
    """``inner`` with the reports of the last window taken off its budget (module docstring).

    Everything else is ``inner``'s: ξ, the window, link statistics, live parameters, and any
    attribute of it (``last_stats`` for the link health, ``stats``...).
    """

    def __init__(self, inner: GoodputConstraint, traffic: ReportTraffic) -> None:
        # no super().__init__: the send record and the window are the inner constraint's
        self.inner = inner
        self.traffic = traffic

    @property
    def window_s(self) -> float:  # type: ignore[override]
        return self.inner.window_s

    def __getattr__(self, name: str) -> Any:
        if name in ("inner", "traffic"):  # not set yet (copy, pickle): no recursion
            raise AttributeError(name)
        return getattr(self.inner, name)

    def limit_bytes_per_s(self, *, now: float) -> float:
        return self.inner.limit_bytes_per_s(now=now)

    def report_bytes(self, *, now: float) -> int:
        """Bytes of receiver reports on the medium in the window ending at ``now``."""
        return self.traffic.bytes_in_window(now=now, window_s=self.inner.window_s)

    def budget_bytes(self, *, now: float) -> float:
        return max(0.0, self.inner.budget_bytes(now=now) - self.report_bytes(now=now))

    def on_sample(self, sample: LinkSample, *, now: float) -> None:
        self.inner.on_sample(sample, now=now)

    def on_samples(self, samples: Iterable[LinkSample], *, now: float) -> None:
        self.inner.on_samples(samples, now=now)

    def on_round_trip(self, round_trip: RoundTrip, *, now: float) -> None:
        self.inner.on_round_trip(round_trip, now=now)

    def on_stall(self, t_from: float, t_to: float, *, now: float) -> None:
        self.inner.on_stall(t_from, t_to, now=now)

    def on_sent(self, size_bytes: int, *, now: float) -> None:
        self.inner.on_sent(size_bytes, now=now)

    def sent_in_window(self, *, now: float) -> int:
        return self.inner.sent_in_window(now=now)

    def admits(self, size_bytes: int, *, now: float) -> bool:
        return (self.sent_in_window(now=now) + size_bytes
                <= self.budget_bytes(now=now))

    def tunable(self) -> dict[str, str]:
        return self.inner.tunable()

    def check_params(self, changes: Mapping[str, object]) -> dict[str, float]:
        return self.inner.check_params(changes)

    def apply_params(self, checked: Mapping[str, float]) -> None:
        self.inner.apply_params(checked)
