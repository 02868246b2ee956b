"""The camera service: frames at ``rate_hz`` from a blocking source, off the event loop.

:class:`CameraService` grabs in a worker thread, resizes to the configured size and hands
each :class:`~companion.camera.Frame` to an async sink; a slow sink makes it skip frames,
never queue. A camera that fails is said once (a WARNING, and ``on_problem`` for the
operator), then every :data:`WARN_EVERY_S` while it stays out, and once more when frames
come again: a camera unplugged in flight logged a WARNING per frame period, five a second.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Awaitable, Callable

import cv2

from companion.camera import CameraError, Frame, FrameSource, Image
from companion.telemetry import TelemetrySnapshot

__all__ = ["TELL_AFTER_S", "WARN_EVERY_S", "CameraService", "FrameSink", "ProblemSink"]

log = logging.getLogger("companion.camera")

FrameSink = Callable[[Frame], Awaitable[None]]
ProblemSink = Callable[[int, str], None]
"""``(severity, text)``, MAVLink severities: 4 (WARNING) when the camera fails, 6 (INFO) when
its frames come again. The companion sends them on its status, as autopilot texts go."""
Clock = Callable[[], float]

WARN_EVERY_S = 30.0
"""A camera that stays out is said again this often."""
TELL_AFTER_S = 2.0
"""An outage is told to the operator once it lasts this long (one image of a folder that
does not decode is a WARNING in the log, not an alert on the dashboard every cycle)."""


class CameraService:
    """Captures at ``rate_hz`` off the event loop and awaits ``sink(frame)`` for each frame.

    The capture runs in a worker thread bounded by ``read_timeout_s``; the resize to
    ``width`` x ``height`` happens there too. Read errors are counted and said as the
    module docstring tells; the service keeps going (a camera that recovers resumes the
    stream, and a live one is opened again: ``LiveCaptureSource(reopen_s=...)``).
    """

    def __init__(self, source: FrameSource, sink: FrameSink, *, clock: Clock, rate_hz: float,
                 width: int, height: int, pose: Callable[[], TelemetrySnapshot] | None = None,
                 read_timeout_s: float = 2.0, on_problem: ProblemSink | None = None) -> None:
        if rate_hz <= 0:
            raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
        self.source = source
        self._sink = sink
        self._clock = clock
        self._period_s = 1.0 / rate_hz
        self._size = (width, height)
        self._pose = pose
        self._read_timeout_s = read_timeout_s
        self._on_problem = on_problem
        self._stopping = asyncio.Event()
        self.counters = {"frames": 0, "empty_reads": 0, "read_errors": 0}
        self._out_since: float | None = None
        """Loop time of the first failed read of the current outage."""
        self._said_at = 0.0
        self._errors_unsaid = 0
        self._told = False

    def _capture(self) -> Image | None:
        image = self.source.read(timeout_s=self._read_timeout_s)
        if image is None:
            return None
        if image.ndim == 2:
            image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
        if (image.shape[1], image.shape[0]) != self._size:
            image = cv2.resize(image, self._size, interpolation=cv2.INTER_AREA)
        return image

    def _read_failed(self, problem: str, now: float) -> None:
        self.counters["read_errors"] += 1
        name = self.source.description
        if self._out_since is None:
            self._out_since = self._said_at = now
            self._errors_unsaid = 0
            log.warning("camera %s: %s", name, problem)
            return
        if not self._told and now - self._out_since >= TELL_AFTER_S:
            self._told = True
            self._tell(4, f"camera: {problem}")
        if now - self._said_at >= WARN_EVERY_S:
            log.warning("camera %s: still no frame after %.0f s (%d failed reads since it "
                        "was last said): %s", name, now - self._out_since,
                        self._errors_unsaid + 1, problem)
            self._said_at, self._errors_unsaid = now, 0
        else:
            self._errors_unsaid += 1

    def _read_ok(self, now: float) -> None:
        if self._out_since is not None:
            log.info("camera %s: frames again after %.1f s", self.source.description,
                     now - self._out_since)
            if self._told:
                self._tell(6, f"camera: frames again after {now - self._out_since:.0f} s")
            self._out_since, self._told = None, False

    def _tell(self, severity: int, text: str) -> None:
        if self._on_problem is not None:
            self._on_problem(severity, text)

    async def run(self) -> None:
        loop = asyncio.get_running_loop()
        index = 0
        try:
            while not self._stopping.is_set():
                t_next = loop.time() + self._period_s
                try:
                    async with asyncio.timeout(self._read_timeout_s + 1.0):
                        image = await asyncio.to_thread(self._capture)
                except (CameraError, TimeoutError, cv2.error) as exc:
                    self._read_failed(str(exc) or "no frame in time", loop.time())
                    image = None
                if image is None:
                    self.counters["empty_reads"] += 1
                else:
                    self._read_ok(loop.time())
                    snap = self._pose() if self._pose is not None else None
                    frame = Frame(image=image, t_capture=self._clock(), index=index,
                                  telemetry=snap)
                    index += 1
                    self.counters["frames"] += 1
                    await self._sink(frame)
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(max(0.0, t_next - loop.time())):
                        await self._stopping.wait()
        finally:
            await asyncio.to_thread(self.source.close)

    def stop(self) -> None:
        self._stopping.set()
