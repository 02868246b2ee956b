"""Frame sources and the camera service: freshest frame, size, rate, skipping when busy."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.camera import (
    CameraError,
    FolderSource,
    Frame,
    LiveCaptureSource,
    VideoFileSource,
    open_source,
)
from companion.camera_service import CameraService
from companion.telemetry import TelemetrySnapshot


def _numbered(i: int, size: tuple[int, int] = (160, 120)) -> np.ndarray:
    """A frame whose grey level encodes its index (JPEG/MJPG-robust: steps of 10)."""
    return np.full((size[1], size[0], 3), 10 * (i % 25), np.uint8)


def _index(image: np.ndarray) -> int:
    return round(float(image.mean()) / 10.0)


def _write_video(path: Path, frames: int, fps: float = 25.0) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"MJPG"), fps, (160, 120))
    assert writer.isOpened()
    for i in range(frames):
        writer.write(_numbered(i))
    writer.release()
    return path


def test_folder_source_cycles_in_name_order(tmp_path: Path) -> None:
    for i in (2, 0, 1):
        cv2.imwrite(str(tmp_path / f"f{i}.png"), _numbered(i))
    (tmp_path / "notes.txt").write_text("not an image")
    source = FolderSource(tmp_path)
    seen = [_index(source.read(timeout_s=1)) for _ in range(4)]  # type: ignore[arg-type]
    assert seen == [0, 1, 2, 0]


def test_empty_folder_is_an_error(tmp_path: Path) -> None:
    with pytest.raises(CameraError, match="no images"):
        FolderSource(tmp_path)


def test_video_file_is_paced_by_skipping(tmp_path: Path) -> None:
    path = _write_video(tmp_path / "v.avi", 20, fps=25.0)
    source = VideoFileSource(path, rate_hz=5.0)  # 25 fps / 5 Hz: every 5th frame
    seen = [_index(source.read(timeout_s=1)) for _ in range(4)]  # type: ignore[arg-type]
    source.close()
    assert seen == [4, 9, 14, 19]


def test_live_capture_returns_the_freshest_frame(tmp_path: Path) -> None:
    path = _write_video(tmp_path / "live.avi", 24)
    source = LiveCaptureSource(str(path))
    try:
        time.sleep(0.3)  # the grab thread drains the whole "driver buffer" meanwhile
        image = source.read(timeout_s=2)
        assert image is not None and _index(image) > 5
    finally:
        source.close()


def test_open_source_names_the_problem(tmp_path: Path) -> None:
    with pytest.raises(CameraError, match="nope"):
        open_source(str(tmp_path / "nope"), width=64, height=48, rate_hz=1)
    with pytest.raises(CameraError, match="'device:front': expected device:N"):
        open_source("device:front", width=64, height=48, rate_hz=1)
    cv2.imwrite(str(tmp_path / "a.jpg"), _numbered(1))
    assert isinstance(open_source(str(tmp_path), width=64, height=48, rate_hz=1), FolderSource)


class CountingSource:
    description = "counting"

    def __init__(self) -> None:
        self.i = 0
        self.closed = False

    def read(self, *, timeout_s: float) -> np.ndarray | None:
        self.i += 1
        return _numbered(self.i, (320, 240))

    def close(self) -> None:
        self.closed = True


async def test_service_resizes_stamps_and_geotags() -> None:
    source = CountingSource()
    frames: list[Frame] = []
    pose = TelemetrySnapshot(lat_deg=1.0, lon_deg=2.0, roll_rad=0.0)
    service: CameraService

    async def sink(frame: Frame) -> None:
        frames.append(frame)
        if len(frames) == 3:
            service.stop()

    service = CameraService(source, sink, clock=lambda: 42.0, rate_hz=50.0, width=64,
                            height=48, pose=lambda: pose)
    async with asyncio.timeout(5):
        await service.run()
    assert [f.index for f in frames] == [0, 1, 2]
    assert all(f.image.shape == (48, 64, 3) and f.t_capture == 42.0 for f in frames)
    assert frames[0].telemetry is pose and source.closed


async def test_service_keeps_running_after_read_errors() -> None:
    class Flaky(CountingSource):
        def read(self, *, timeout_s: float) -> np.ndarray | None:
            self.i += 1
            if self.i % 2:
                raise CameraError("glitch")
            return _numbered(self.i)

    frames: list[Frame] = []
    service: CameraService

    async def sink(frame: Frame) -> None:
        frames.append(frame)
        if len(frames) == 2:
            service.stop()

    service = CameraService(Flaky(), sink, clock=time.time, rate_hz=100.0, width=160,
                            height=120)
    async with asyncio.timeout(5):
        await service.run()
    assert service.counters["read_errors"] >= 2 and len(frames) == 2


def test_synthetic_source_renders_from_the_telemetry_pose() -> None:
    pytest.importorskip("sitl.camera")
    from sitl.scenes import load_scene

    home = load_scene("demo").home
    pose = TelemetrySnapshot(lat_deg=home.lat_deg, lon_deg=home.lon_deg, alt_rel_m=30.0,
                             roll_rad=0.0, pitch_rad=0.0, yaw_rad=0.0)
    source = open_source("synthetic", width=320, height=240, rate_hz=5, pose=lambda: pose,
                         options={"scene": "demo", "noise_std": 0.0})
    image = source.read(timeout_s=1)
    assert image is not None and image.shape == (240, 320, 3)
    unknown = open_source("synthetic", width=64, height=48, rate_hz=5,
                          pose=TelemetrySnapshot)
    assert unknown.read(timeout_s=1) is None  # no position yet
    with pytest.raises(CameraError, match="nowhere"):
        open_source("synthetic", width=64, height=48, rate_hz=5, pose=TelemetrySnapshot,
                    options={"scene": "nowhere"})


def test_a_registered_frame_source_is_opened_by_its_name(monkeypatch: pytest.MonkeyPatch
                                                         ) -> None:
    """A new kind of camera is one SourceKind and one register line; errors list it."""
    import companion.camera as camera

    monkeypatch.setattr(camera, "_REGISTERED", [])

    class Grey:
        description = "grey"

        def __init__(self, request: camera.SourceRequest) -> None:
            self.image = np.full((request.height, request.width, 3), request.options["level"],
                                 np.uint8)

        def read(self, *, timeout_s: float) -> np.ndarray:
            return self.image

        def close(self) -> None:
            pass

    kind = camera.SourceKind(name="grey", describe="'grey'", claims=lambda s: s == "grey",
                             open=Grey)
    camera.register_frame_source(kind)
    source = open_source("grey", width=32, height=24, rate_hz=1, options={"level": 7})
    image = source.read(timeout_s=1)
    assert image is not None and image.shape == (24, 32, 3) and int(image.max()) == 7
    with pytest.raises(CameraError, match=r"'/no/such': not 'grey', 'synthetic', a device, "
                                          r"a GStreamer pipeline, a URL, a folder or an "
                                          r"existing video file"):
        open_source("/no/such", width=32, height=24, rate_hz=1)
    with pytest.raises(ValueError, match="registered already"):
        camera.register_frame_source(kind)
