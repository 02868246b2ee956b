"""Frame sources and the camera service: the freshest frame, at a set size and rate, off the loop.

Sources (all blocking, used from worker threads only):

* :class:`LiveCaptureSource`: a V4L2 device (``/dev/video0`` or ``device:0``), a GStreamer
  pipeline (a string with ``!``) or a network URL (``rtsp://``, ``http://``). A grab thread
  reads continuously and keeps only the newest frame, so the driver's buffer never holds
  stale frames and ``read`` always returns the freshest one.
* :class:`VideoFileSource`: a video file, paced to the wanted rate by skipping frames.
* :class:`FolderSource`: a folder of images, cycled in name order.
* :class:`SyntheticSource`: renders what the drone sees from the telemetry pose
  (``sitl.camera.SyntheticCamera``), for SITL runs.

:class:`CameraService` grabs at ``rate_hz`` in a worker thread, resizes to the configured size
and hands each :class:`Frame` to an async sink; a slow sink makes it skip frames, never queue.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import cv2
import numpy.typing as npt

from companion.telemetry import TelemetrySnapshot

__all__ = [
    "CameraError",
    "CameraService",
    "FolderSource",
    "Frame",
    "FrameSource",
    "LiveCaptureSource",
    "SyntheticSource",
    "VideoFileSource",
    "open_source",
]

log = logging.getLogger(__name__)

Image = npt.NDArray[Any]
Clock = Callable[[], float]
IMAGE_SUFFIXES = frozenset({".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp"})
VIDEO_SUFFIXES = frozenset({".mp4", ".avi", ".mkv", ".mov", ".webm", ".mjpeg", ".mjpg"})


class CameraError(RuntimeError):
    """A camera that cannot be opened or read; the text names the source."""


@dataclass(frozen=True, slots=True, kw_only=True)
class Frame:
    """One captured frame (BGR uint8) with its capture time on the fleet clock."""

    image: Image
    t_capture: float
    index: int
    telemetry: TelemetrySnapshot | None = None
    """Vehicle state at capture (position and attitude for the geotag)."""


class FrameSource(Protocol):
    """A blocking frame source; ``read`` returns the freshest frame or None if none yet."""

    description: str

    def read(self, *, timeout_s: float) -> Image | None: ...

    def close(self) -> None: ...


class LiveCaptureSource:
    """A live OpenCV capture drained by its own grab thread (always the freshest frame)."""

    def __init__(self, target: str | int, *, api: int = cv2.CAP_ANY, width: int | None = None,
                 height: int | None = None, fps: float | None = None) -> None:
        self.description = f"live:{target}"
        self._cap = cv2.VideoCapture(target, api)
        if not self._cap.isOpened():
            raise CameraError(f"cannot open camera {target!r}")
        with contextlib.suppress(cv2.error):
            self._cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)
            if width:
                self._cap.set(cv2.CAP_PROP_FRAME_WIDTH, width)
            if height:
                self._cap.set(cv2.CAP_PROP_FRAME_HEIGHT, height)
            if fps:
                self._cap.set(cv2.CAP_PROP_FPS, fps)
        self._cond = threading.Condition()
        self._latest: Image | None = None
        self._fresh = False
        self._failed: str | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._grab, name="camera-grab", daemon=True)
        self._thread.start()

    def _grab(self) -> None:
        failures = 0
        while not self._stop.is_set():
            ok, image = self._cap.read()
            if not ok or image is None:
                failures += 1
                if failures >= 50:
                    with self._cond:
                        self._failed = f"{self.description}: no frame in 50 reads"
                        self._cond.notify_all()
                    return
                self._stop.wait(0.02)
                continue
            failures = 0
            with self._cond:
                self._latest = image
                self._fresh = True
                self._cond.notify_all()

    def read(self, *, timeout_s: float) -> Image | None:
        with self._cond:
            self._cond.wait_for(lambda: self._fresh or self._failed is not None, timeout_s)
            if self._failed is not None and not self._fresh:
                raise CameraError(self._failed)
            self._fresh = False
            return self._latest

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self._cap.release()


class VideoFileSource:
    """A video file played at ``rate_hz``: frames in between are skipped; loops at the end."""

    def __init__(self, path: str | Path, *, rate_hz: float, loop: bool = True) -> None:
        self.description = f"file:{path}"
        self._path = str(path)
        self._cap = cv2.VideoCapture(self._path)
        if not self._cap.isOpened():
            raise CameraError(f"cannot open video file {self._path!r}")
        fps = self._cap.get(cv2.CAP_PROP_FPS) or rate_hz
        self._skip = max(0, round(fps / rate_hz) - 1) if rate_hz > 0 else 0
        self._loop = loop

    def read(self, *, timeout_s: float) -> Image | None:
        for _ in range(self._skip):
            self._cap.grab()
        ok, image = self._cap.read()
        if not ok and self._loop:
            self._cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
            ok, image = self._cap.read()
        return image if ok else None

    def close(self) -> None:
        self._cap.release()


class FolderSource:
    """The images of a folder in name order, cycled."""

    def __init__(self, folder: str | Path, *, loop: bool = True) -> None:
        self.description = f"folder:{folder}"
        self._files = sorted(p for p in Path(folder).iterdir()
                             if p.suffix.lower() in IMAGE_SUFFIXES)
        if not self._files:
            raise CameraError(f"no images ({', '.join(sorted(IMAGE_SUFFIXES))}) in {folder}")
        self._next = 0
        self._loop = loop

    def read(self, *, timeout_s: float) -> Image | None:
        if self._next >= len(self._files):
            if not self._loop:
                return None
            self._next = 0
        path = self._files[self._next]
        self._next += 1
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if image is None:
            raise CameraError(f"cannot decode image {path}")
        return image

    def close(self) -> None:
        pass


class SyntheticSource:
    """Frames rendered from the current telemetry pose (``render(snapshot) -> BGR image``)."""

    def __init__(self, render: Callable[[TelemetrySnapshot], Image | None],
                 pose: Callable[[], TelemetrySnapshot], *, description: str = "synthetic"
                 ) -> None:
        self.description = description
        self._render = render
        self._pose = pose

    def read(self, *, timeout_s: float) -> Image | None:
        return self._render(self._pose())

    def close(self) -> None:
        pass


def _sitl_renderer(width: int, height: int, options: dict[str, Any]
                   ) -> Callable[[TelemetrySnapshot], Image | None]:
    """Adapter to ``sitl.camera.SyntheticCamera`` (imported lazily: sitl depends on us).

    ``options``: ``scene`` (bundled name or TOML path, default ``demo``) and the camera's own
    keywords (``hfov_deg``, ``mount_pitch_deg``, ``gimbal_stabilised``, ``noise_std``,
    ``lighting``, ``seed``).
    """
    import time

    try:
        from sitl.camera import SyntheticCamera, pose_from_geo
        from sitl.scenes import SceneError, load_scene
    except ImportError as exc:
        raise CameraError(f"synthetic camera unavailable: {exc}") from exc
    options = dict(options)
    scene_name = str(options.pop("scene", "demo"))
    try:
        scene = load_scene(scene_name)
        camera = SyntheticCamera(scene, width_px=width, height_px=height, **options)
    except (SceneError, TypeError, ValueError) as exc:
        raise CameraError(f"synthetic camera (scene {scene_name!r}): {exc}") from exc
    t_start = time.monotonic()

    def render(snap: TelemetrySnapshot) -> Image | None:
        if snap.lat_deg is None or snap.lon_deg is None:
            return None  # no position yet: nothing to look at
        pose = pose_from_geo(scene.home, lat_deg=snap.lat_deg, lon_deg=snap.lon_deg,
                             alt_rel_m=snap.alt_rel_m if snap.alt_rel_m is not None else 0.0,
                             roll_rad=snap.roll_rad or 0.0, pitch_rad=snap.pitch_rad or 0.0,
                             yaw_rad=snap.yaw_rad or 0.0)
        image: Image = camera.render(pose, t_s=time.monotonic() - t_start)
        return image

    return render


def open_source(source: str, *, width: int, height: int, rate_hz: float,
                pose: Callable[[], TelemetrySnapshot] | None = None,
                options: dict[str, Any] | None = None) -> FrameSource:
    """Open the source a configuration string names (see the module docstring)."""
    if source == "synthetic":
        if pose is None:
            raise CameraError("the synthetic camera needs the telemetry pose")
        return SyntheticSource(_sitl_renderer(width, height, dict(options or {})), pose)
    if source.startswith("device:"):
        return LiveCaptureSource(int(source.removeprefix("device:")), api=cv2.CAP_V4L2,
                                 width=width, height=height, fps=rate_hz)
    if source.startswith("/dev/video"):
        return LiveCaptureSource(source, api=cv2.CAP_V4L2, width=width, height=height,
                                 fps=rate_hz)
    if "!" in source:
        return LiveCaptureSource(source, api=cv2.CAP_GSTREAMER)
    if "://" in source:
        return LiveCaptureSource(source, api=cv2.CAP_FFMPEG)
    path = Path(source)
    if path.is_dir():
        return FolderSource(path)
    if path.is_file():
        return VideoFileSource(path, rate_hz=rate_hz)
    raise CameraError(f"camera source {source!r}: not 'synthetic', a device, a URL, a "
                      "GStreamer pipeline, a folder or an existing video file")


FrameSink = Callable[[Frame], Awaitable[None]]


class CameraService:
    """Captures at ``rate_hz`` off the event loop and awaits ``sink(frame)`` for each frame.

    The capture runs in a worker thread bounded by ``read_timeout_s``; the resize to
    ``width`` x ``height`` happens there too. Read errors are logged and counted; the service
    keeps going (a camera that recovers resumes the stream).
    """

    def __init__(self, source: FrameSource, sink: FrameSink, *, clock: Clock, rate_hz: float,
                 width: int, height: int, pose: Callable[[], TelemetrySnapshot] | None = None,
                 read_timeout_s: float = 2.0) -> None:
        if rate_hz <= 0:
            raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
        self.source = source
        self._sink = sink
        self._clock = clock
        self._period_s = 1.0 / rate_hz
        self._size = (width, height)
        self._pose = pose
        self._read_timeout_s = read_timeout_s
        self._stopping = asyncio.Event()
        self.counters = {"frames": 0, "empty_reads": 0, "read_errors": 0}

    def _capture(self) -> Image | None:
        image = self.source.read(timeout_s=self._read_timeout_s)
        if image is None:
            return None
        if image.ndim == 2:
            image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
        if (image.shape[1], image.shape[0]) != self._size:
            image = cv2.resize(image, self._size, interpolation=cv2.INTER_AREA)
        return image

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
                    self.counters["read_errors"] += 1
                    log.warning("camera %s: %s", self.source.description, exc or "timeout")
                    image = None
                if image is None:
                    self.counters["empty_reads"] += 1
                else:
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
