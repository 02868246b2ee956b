"""A camera that cannot be opened, or that stops giving frames in flight, is opened again;
the companion runs on without it, says so once, and says when frames come again.

Before: a live camera that could not be opened stopped ``uav-companion run`` (exit 2: no
telemetry either, and under systemd a restart every 2 s); one that stopped giving frames
(a USB camera unplugged) was never read again until the companion restarted, and its
service logged a WARNING every frame period, five a second.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest

import companion.camera_service as camera_service
from companion.camera import CameraError, Frame, LiveCaptureSource, open_source
from companion.camera_service import CameraService


class FakeCapture:
    """A cv2.VideoCapture as far as the grab thread uses it: frames until ``frames`` run out,
    then no frame (a device unplugged answers every read False)."""

    def __init__(self, opened: bool, frames: int) -> None:
        self.opened = opened
        self.frames = frames
        self.released = False

    def isOpened(self) -> bool:  # OpenCV's name
        return self.opened

    def set(self, prop: int, value: float) -> bool:
        return True

    def read(self) -> tuple[bool, np.ndarray | None]:
        time.sleep(0.001)
        if self.frames <= 0:
            return False, None
        self.frames -= 1
        return True, np.full((48, 64, 3), 7, np.uint8)

    def release(self) -> None:
        self.released = True


class Captures:
    """The captures a source opens, one after another: ``plan`` says of each whether it
    opens and how many frames it gives; after the plan, every capture opens and gives
    frames."""

    def __init__(self, plan: list[tuple[bool, int]]) -> None:
        self.plan = list(plan)
        self.made: list[FakeCapture] = []
        self.lock = threading.Lock()

    def __call__(self) -> FakeCapture:
        with self.lock:
            opened, frames = self.plan.pop(0) if self.plan else (True, 10**9)
            self.made.append(FakeCapture(opened, frames))
            return self.made[-1]


def frames_again(source: LiveCaptureSource, timeout_s: float) -> list[str]:
    """Reads until a frame comes; the problems read on the way."""
    problems: list[str] = []
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            if source.read(timeout_s=0.2) is not None:
                return problems
        except CameraError as exc:
            problems.append(str(exc))
            time.sleep(0.02)
    raise AssertionError(f"no frame in {timeout_s} s: {problems[-3:]}")


@pytest.fixture
def sources() -> Iterator[list[LiveCaptureSource]]:
    made: list[LiveCaptureSource] = []
    yield made
    for source in made:
        source.close()


def test_a_camera_that_cannot_be_opened_yet_is_opened_when_it_can(
        sources: list[LiveCaptureSource]) -> None:
    captures = Captures([(False, 0), (False, 0), (False, 0)])
    source = LiveCaptureSource("/dev/video7", reopen_s=0.05, capture=captures)
    sources.append(source)
    problems = frames_again(source, 5.0)
    assert problems and problems[0] == (
        "cannot open camera '/dev/video7' (trying again every 0.05 s)")
    assert [c.opened for c in captures.made] == [False, False, False, True]
    assert all(c.released for c in captures.made[:3])


def test_a_camera_lost_in_flight_is_opened_again(sources: list[LiveCaptureSource]) -> None:
    captures = Captures([(True, 5), (False, 0)])
    source = LiveCaptureSource(0, reopen_s=0.05, capture=captures)
    sources.append(source)
    assert source.read(timeout_s=2.0) is not None
    with pytest.raises(CameraError) as lost:  # its 5 frames read, then 50 reads of none
        for _ in range(100):
            source.read(timeout_s=0.5)
    assert str(lost.value) == "live:0: no frame in 50 reads (opening it again every 0.05 s)"
    frames_again(source, 10.0)
    assert len(captures.made) == 3 and captures.made[0].released


def test_without_reopen_a_camera_that_cannot_be_opened_raises_at_once() -> None:
    """``uav-companion check`` probes this way: it must say the camera is not there."""
    with pytest.raises(CameraError, match=r"cannot open camera '/dev/video7'$"):
        LiveCaptureSource("/dev/video7", capture=Captures([(False, 0)]))
    with pytest.raises(CameraError, match="cannot open camera"):
        open_source("/dev/video-not-here", width=64, height=48, rate_hz=5)
    missing = open_source("/dev/video-not-here", width=64, height=48, rate_hz=5, reopen_s=30)
    try:
        with pytest.raises(CameraError, match="trying again every 30 s"):
            missing.read(timeout_s=0.1)
    finally:
        missing.close()


class Outage:
    """A source that fails (CameraError) from ``fail_from`` s to ``fail_until`` s."""

    description = "live:test"

    def __init__(self, fail_from: float, fail_until: float) -> None:
        self.t0 = time.monotonic()
        self.window = (fail_from, fail_until)

    def read(self, *, timeout_s: float) -> np.ndarray | None:
        t = time.monotonic() - self.t0
        if self.window[0] <= t < self.window[1]:
            raise CameraError("live:test: no frame in 50 reads")
        return np.zeros((48, 64, 3), np.uint8)

    def close(self) -> None:
        pass


async def test_an_outage_is_said_once_then_seldom_and_its_end_once(
        monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture) -> None:
    monkeypatch.setattr(camera_service, "TELL_AFTER_S", 0.3)
    monkeypatch.setattr(camera_service, "WARN_EVERY_S", 0.5)
    told: list[tuple[int, str]] = []
    frames: list[float] = []

    async def sink(frame: Frame) -> None:
        frames.append(time.monotonic())

    service = CameraService(Outage(0.2, 1.4), sink, clock=time.time, rate_hz=50.0, width=64,
                            height=48, on_problem=lambda sev, text: told.append((sev, text)))
    caplog.set_level(logging.INFO, logger="companion.camera")
    task = asyncio.create_task(service.run())
    await asyncio.sleep(1.9)
    service.stop()
    await asyncio.wait_for(task, 5)
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    infos = [r.getMessage() for r in caplog.records if r.levelno == logging.INFO]
    # ~60 failed reads at 50 Hz: the first, then one every 0.5 s (before: ~60 WARNINGs)
    assert service.counters["read_errors"] >= 40
    assert warnings[0] == "camera live:test: live:test: no frame in 50 reads"
    assert 2 <= len(warnings) <= 4, warnings
    assert all("still no frame after" in w for w in warnings[1:])
    assert len(infos) == 1 and infos[0].startswith("camera live:test: frames again after 1.")
    assert told == [(4, "camera: live:test: no frame in 50 reads"),
                    (6, "camera: frames again after 1 s")]
    assert frames and frames[-1] - frames[0] > 1.4  # frames before and after the outage


async def test_a_glitch_shorter_than_the_telling_time_is_only_logged(
        caplog: pytest.LogCaptureFixture) -> None:
    told: list[tuple[int, str]] = []

    async def sink(frame: Frame) -> None:
        pass

    service = CameraService(Outage(0.1, 0.2), sink, clock=time.time, rate_hz=50.0, width=64,
                            height=48, on_problem=lambda sev, text: told.append((sev, text)))
    caplog.set_level(logging.INFO, logger="companion.camera")
    task = asyncio.create_task(service.run())
    await asyncio.sleep(0.6)
    service.stop()
    await asyncio.wait_for(task, 5)
    assert told == []
    assert [r.levelname for r in caplog.records] == ["WARNING", "INFO"]
