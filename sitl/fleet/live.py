"""Live view of a run: the ground station's HTTP API, and counters from the growing logs.

The progress line counts log lines as they are appended (complete lines only); the numbers
of the summary come from :mod:`sitl.fleet.summary`, which reads the finished logs. The logs
are read at different lags (a companion flushes its log once a second, the station after
every stored batch), so the line's *received* counts an image once its companion's log
shows it sent: it showed ``s1 r2`` and ``s4 r6`` in a 40 s run, more received than sent.
"""

from __future__ import annotations

import json
import urllib.request
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sitl.fleet_config import DroneSlot
from utility_specs.log import message_from_record


@dataclass(slots=True)
class GroundStationApi:
    base_url: str
    token: str
    opener: Callable[..., Any] = urllib.request.urlopen

    def _call(self, method: str, path: str, body: dict[str, Any] | None = None,
              timeout_s: float = 3.0) -> Any:
        data = None if body is None else json.dumps(body).encode()
        request = urllib.request.Request(
            self.base_url + path, data=data, method=method,
            headers={"Authorization": f"Bearer {self.token}",
                     "Content-Type": "application/json"})
        with self.opener(request, timeout=timeout_s) as response:
            return json.loads(response.read().decode())

    def get(self, path: str) -> Any:
        return self._call("GET", path)

    def post(self, path: str, body: dict[str, Any]) -> Any:
        return self._call("POST", path, body)


def _new_lines(path: Path, offset: int) -> tuple[list[bytes], int]:
    """Whole lines appended to a growing log since ``offset``, and the offset after them."""
    try:
        with path.open("rb") as f:
            f.seek(offset)
            chunk = f.read()
    except OSError:
        return [], offset
    end = chunk.rfind(b"\n") + 1
    return chunk[:end].splitlines(), offset + end

ImageKey = tuple[int, float]
"""An image of one sender in both logs: (seq, t_gen)."""


def _image_key(line: bytes) -> ImageKey | None:
    try:
        record = json.loads(line)
        return int(record["seq"]), float(record["t_gen"])
    except (ValueError, TypeError, KeyError, RecursionError):
        return None


@dataclass(slots=True)
class LogTail:
    """Counts image records of a growing companion log (complete lines only)."""

    path: Path
    generated: int = 0
    sent: int = 0
    sent_keys: set[ImageKey] = field(default_factory=set)
    _offset: int = 0

    def poll(self) -> None:
        lines, self._offset = _new_lines(self.path, self._offset)
        for line in lines:
            if b'"type":"image"' not in line:
                continue
            self.generated += 1
            if b'"t_sent":null' not in line:
                self.sent += 1
                key = _image_key(line)
                if key is not None:
                    self.sent_keys.add(key)


@dataclass(slots=True)
class StationTail:
    """Per sender, images the station logged as received, and their recent arrivals."""

    path: Path
    window_s: float = 5.0
    received: dict[str, int] = field(default_factory=dict)
    recent: dict[str, deque[tuple[float, float]]] = field(default_factory=dict)
    """sender -> (t_rcv, latency) of the images of the last ``window_s``."""
    unconfirmed: dict[str, list[ImageKey]] = field(default_factory=dict)
    """sender -> images received whose sending its companion's log does not show yet."""
    confirmed: dict[str, int] = field(default_factory=dict)
    _offset: int = 0

    def poll(self) -> None:
        lines, self._offset = _new_lines(self.path, self._offset)
        for line in lines:
            if b'"type": "image"' not in line and b'"type":"image"' not in line:
                continue
            try:
                m = message_from_record(json.loads(line))
            except (ValueError, TypeError, RecursionError):  # MessageError is a ValueError
                continue
            if m.type != "image" or m.t_rcv is None:
                continue
            self.received[m.sender] = self.received.get(m.sender, 0) + 1
            self.recent.setdefault(m.sender, deque()).append((m.t_rcv, m.t_rcv - m.t_gen))
            self.unconfirmed.setdefault(m.sender, []).append((m.seq, m.t_gen))

    def received_of_sent(self, sender: str, sent: set[ImageKey]) -> int:
        """Images of ``sender`` received among those ``sent`` (its companion's log so far);
        one received before its companion's log shows it counts once that log does."""
        waiting = self.unconfirmed.get(sender, [])
        if waiting:
            self.unconfirmed[sender] = [k for k in waiting if k not in sent]
            self.confirmed[sender] = (self.confirmed.get(sender, 0) + len(waiting)
                                      - len(self.unconfirmed[sender]))
        return self.confirmed.get(sender, 0)

    def rate(self, sender: str, now: float) -> tuple[float, float | None]:
        """Images/s received over the last ``window_s`` and their mean latency (s)."""
        q = self.recent.get(sender, deque())
        while q and q[0][0] < now - self.window_s:
            q.popleft()
        latency = sum(x for _, x in q) / len(q) if q else None
        return len(q) / self.window_s, latency


PROGRESS_LEGEND = ("per drone: images generated (g) and sent (s) by its log, received (r) "
                   "of those sent, received images/s and their latency over the last 5 s")
"""Printed once above the progress lines: ``drone3 g144 s8 r8 0.2/s 120ms`` is opaque to
someone who has not read docs/fleet.md."""


def progress_line(elapsed_s: float, drones: Sequence[DroneSlot], tails: dict[str, LogTail],
                  station: StationTail, now: float) -> str:
    """``[  12 s] drone1 g60 s20 r19 3.8/s 41ms | ...``: images generated, sent (companion
    log), received of those sent (station log), received frame rate and latency over the
    last seconds."""
    parts = []
    for slot in drones:
        tail = tails[slot.drone_id]
        fps, latency = station.rate(slot.drone_id, now)
        lat = "-" if latency is None else f"{1000 * latency:.0f}ms"
        parts.append(f"{slot.drone_id} g{tail.generated} s{tail.sent} "
                     f"r{station.received_of_sent(slot.drone_id, tail.sent_keys)} "
                     f"{fps:.1f}/s {lat}")
    return f"[{elapsed_s:5.0f} s] " + " | ".join(parts)
