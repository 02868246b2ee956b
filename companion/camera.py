"""Frame sources: the freshest frame of a camera, a video file or a folder of images.

Sources (all blocking, used from worker threads only):

* :class:`LiveCaptureSource`: a V4L2 device (``/dev/video0`` or ``device:0``), a GStreamer
  pipeline (a string with ``!``) or a network URL (``rtsp://``, ``http://``). A grab thread
  reads continuously and keeps only the newest frame, so the driver's buffer never holds
  stale frames and ``read`` always returns the freshest one.
* :class:`VideoFileSource`: a video file, paced to the wanted rate by skipping frames.
* :class:`FolderSource`: a folder of images, cycled in name order.

Each kind of source is a :class:`SourceKind` (which ``camera.source`` strings it takes, how to
open one): the built-in ones above, those added with :func:`register_frame_source`, and those
installed packages declare as entry points (group ``uav_infodist.frame_sources``): ``sitl``
adds ``synthetic`` that way, the SITL camera rendered from the telemetry pose, so the companion
never imports the simulator.

:class:`companion.camera_service.CameraService` reads them at a set rate, off the loop.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any, Protocol

import cv2
import numpy.typing as npt

from companion.telemetry import TelemetrySnapshot

__all__ = [
    "CameraError",
    "FolderSource",
    "Frame",
    "FrameSource",
    "LiveCaptureSource",
    "SourceKind",
    "SourceRequest",
    "VideoFileSource",
    "find_source_kind",
    "open_source",
    "register_frame_source",
]


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


def quiet_opencv() -> None:
    """OpenCV's own warnings ("can't open camera by index") went to stderr between the JSON
    log lines, three lines at every attempt to open; the companion says it once, in its log."""
    with contextlib.suppress(AttributeError, cv2.error):
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)


class LiveCaptureSource:
    """A live OpenCV capture drained by its own grab thread (always the freshest frame).

    With ``reopen_s`` (the companion's own cameras) a device that cannot be opened, or that
    stops giving frames (a USB camera unplugged by the vibration of a flight), is opened
    again every ``reopen_s`` until it gives frames; reads raise :class:`CameraError` in the
    meantime. Before, such a camera stopped the companion at start (no telemetry either),
    and one lost in flight was never read again until the companion restarted. Without
    ``reopen_s`` (``uav-companion check``) a camera that cannot be opened raises at once."""

    FAILED_READS = 50
    """Reads without a frame in a row that make the capture lost."""

    def __init__(self, target: str | int, *, api: int = cv2.CAP_ANY, width: int | None = None,
                 height: int | None = None, fps: float | None = None,
                 reopen_s: float | None = None,
                 capture: Callable[[], Any] | None = None) -> None:
        self.description = f"live:{target}"
        quiet_opencv()
        self._target = target
        self._new_capture = capture or (lambda: cv2.VideoCapture(target, api))
        self._settings = (width, height, fps)
        self._reopen_s = reopen_s
        self._cond = threading.Condition()
        self._latest: Image | None = None
        self._fresh = False
        self._failed: str | None = None
        self._stop = threading.Event()
        self._cap = self._open()
        if self._cap is None:
            if reopen_s is None:
                raise CameraError(f"cannot open camera {target!r}")
            self._failed = f"cannot open camera {target!r} (trying again every {reopen_s:g} s)"
        self._thread = threading.Thread(target=self._grab, name="camera-grab", daemon=True)
        self._thread.start()

    def _open(self) -> Any:
        cap = self._new_capture()
        if not cap.isOpened():
            cap.release()
            return None
        width, height, fps = self._settings
        with contextlib.suppress(cv2.error):
            cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)
            if width:
                cap.set(cv2.CAP_PROP_FRAME_WIDTH, width)
            if height:
                cap.set(cv2.CAP_PROP_FRAME_HEIGHT, height)
            if fps:
                cap.set(cv2.CAP_PROP_FPS, fps)
        return cap

    def _set_failed(self, text: str) -> None:
        with self._cond:
            self._failed = text
            self._cond.notify_all()

    def _grab(self) -> None:
        failures = 0
        while not self._stop.is_set():
            if self._cap is None:  # lost or never opened, and reopen_s is set
                if self._stop.wait(self._reopen_s):
                    return
                self._cap = self._open()
                failures = 0
                continue
            ok, image = self._cap.read()
            if not ok or image is None:
                failures += 1
                if failures >= self.FAILED_READS:
                    text = f"{self.description}: no frame in {failures} reads"
                    if self._reopen_s is None:
                        self._set_failed(text)
                        return
                    self._set_failed(f"{text} (opening it again every {self._reopen_s:g} s)")
                    self._cap.release()
                    self._cap = None
                    continue
                self._stop.wait(0.02)
                continue
            failures = 0
            with self._cond:
                self._latest = image
                self._fresh = True
                self._failed = None
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
        if self._cap is not None and not self._thread.is_alive():
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


@dataclass(frozen=True, slots=True, kw_only=True)
class SourceRequest:
    """What the configuration asks of a frame source (``[camera]``)."""

    source: str
    width: int
    height: int
    rate_hz: float
    pose: Callable[[], TelemetrySnapshot] | None = None
    """The vehicle's current state, for sources that render what it sees."""
    options: Mapping[str, Any] = field(default_factory=dict)
    """``camera.options``: the source's own keywords."""
    reopen_s: float | None = None
    """A live source that cannot be opened or stops giving frames is opened again this often
    (None: it raises :class:`CameraError`, for a probe)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class SourceKind:
    """One kind of frame source: which ``camera.source`` strings it takes and how to open one."""

    name: str
    describe: str
    """How error messages list it ("a folder")."""
    claims: Callable[[str], bool]
    open: Callable[[SourceRequest], FrameSource]


def _device(request: SourceRequest) -> FrameSource:
    target: str | int = request.source
    if request.source.startswith("device:"):
        number = request.source.removeprefix("device:")
        if not number.isdigit():
            raise CameraError(f"camera source {request.source!r}: expected device:N, "
                              "N the V4L2 device number")
        target = int(number)
    return LiveCaptureSource(target, api=cv2.CAP_V4L2, width=request.width,
                             height=request.height, fps=request.rate_hz,
                             reopen_s=request.reopen_s)


BUILTIN_SOURCES: tuple[SourceKind, ...] = (
    SourceKind(name="device", describe="a device",
               claims=lambda s: s.startswith(("device:", "/dev/video")), open=_device),
    SourceKind(name="gstreamer", describe="a GStreamer pipeline", claims=lambda s: "!" in s,
               open=lambda r: LiveCaptureSource(r.source, api=cv2.CAP_GSTREAMER,
                                                reopen_s=r.reopen_s)),
    SourceKind(name="url", describe="a URL", claims=lambda s: "://" in s,
               open=lambda r: LiveCaptureSource(r.source, api=cv2.CAP_FFMPEG,
                                                reopen_s=r.reopen_s)),
    SourceKind(name="folder", describe="a folder", claims=lambda s: Path(s).is_dir(),
               open=lambda r: FolderSource(r.source)),
    SourceKind(name="file", describe="an existing video file",
               claims=lambda s: Path(s).is_file(),
               open=lambda r: VideoFileSource(r.source, rate_hz=r.rate_hz)),
)
"""Tried in this order after the registered and entry-point kinds."""

ENTRY_POINT_GROUP = "uav_infodist.frame_sources"
"""Installed packages add named kinds here: ``NAME = "module:SOURCE_KIND"`` (sitl adds
``synthetic``); a kind is loaded only when ``camera.source`` is its name."""

_REGISTERED: list[SourceKind] = []


def register_frame_source(kind: SourceKind) -> None:
    """Add a kind of frame source; it is asked before the entry points and built-ins."""
    if any(k.name == kind.name for k in _REGISTERED):
        raise ValueError(f"a frame source named {kind.name!r} is registered already")
    _REGISTERED.append(kind)


def find_source_kind(source: str) -> SourceKind | None:
    """The kind that takes ``source``: registered, then entry points (by name), then built-in."""
    for kind in _REGISTERED:
        if kind.claims(source):
            return kind
    for point in entry_points(group=ENTRY_POINT_GROUP):
        if point.name == source:
            try:
                kind = point.load()
            except Exception as exc:  # a broken plug-in is a camera error, not a crash
                raise CameraError(f"camera source {source!r} ({point.value}) cannot be "
                                  f"loaded: {exc!r}") from exc
            if not isinstance(kind, SourceKind):
                raise CameraError(f"camera source {source!r}: {point.value} is not a "
                                  "companion.camera.SourceKind")
            return kind
    return next((kind for kind in BUILTIN_SOURCES if kind.claims(source)), None)


def source_kinds_text() -> str:
    """Every kind, as error messages list them: "'synthetic', a device, ... or a folder"."""
    names = [*(repr(k.name) for k in _REGISTERED),
             *(repr(p.name) for p in entry_points(group=ENTRY_POINT_GROUP)),
             *(k.describe for k in BUILTIN_SOURCES)]
    return ", ".join(names[:-1]) + " or " + names[-1]


def open_source(source: str, *, width: int, height: int, rate_hz: float,
                pose: Callable[[], TelemetrySnapshot] | None = None,
                options: Mapping[str, Any] | None = None,
                reopen_s: float | None = None) -> FrameSource:
    """Open the source a configuration string names (the first kind that claims it)."""
    kind = find_source_kind(source)
    if kind is None:
        raise CameraError(f"camera source {source!r}: not {source_kinds_text()}")
    return kind.open(SourceRequest(source=source, width=width, height=height, rate_hz=rate_hz,
                                   pose=pose, options=dict(options or {}), reopen_s=reopen_s))
