"""The synthetic camera as a companion frame source: ``camera.source = "synthetic"``.

Declared as the entry point ``synthetic`` of the group ``uav_infodist.frame_sources``
(pyproject.toml), so ``uav-companion`` finds it when this package is installed without
importing ``sitl`` itself. ``camera.options``: ``scene`` (bundled name or TOML path, default
``demo``) and the camera's own keywords (``hfov_deg``, ``mount_pitch_deg``,
``gimbal_stabilised``, ``noise_std``, ``lighting``, ``seed``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from companion.camera import CameraError, FrameSource, SourceKind, SourceRequest
from companion.telemetry import TelemetrySnapshot
from sitl.camera import SyntheticCamera, pose_from_geo
from sitl.scenes import SceneError, load_scene

__all__ = ["SYNTHETIC", "SyntheticSource"]

Image = Any
Render = Callable[[TelemetrySnapshot], Image | None]


class SyntheticSource:
    """Frames rendered from the current telemetry pose (``render(snapshot) -> BGR image``)."""

    def __init__(self, render: Render, pose: Callable[[], TelemetrySnapshot], *,
                 description: str = "synthetic") -> None:
        self.description = description
        self._render = render
        self._pose = pose

    def read(self, *, timeout_s: float) -> Image | None:
        return self._render(self._pose())

    def close(self) -> None:
        pass


def _renderer(width: int, height: int, options: dict[str, Any]) -> Render:
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
        return camera.render(pose, t_s=time.monotonic() - t_start)

    return render


def open_synthetic(request: SourceRequest) -> FrameSource:
    if request.pose is None:
        raise CameraError("the synthetic camera needs the telemetry pose")
    return SyntheticSource(_renderer(request.width, request.height, dict(request.options)),
                           request.pose)


SYNTHETIC = SourceKind(name="synthetic", describe="'synthetic' (the SITL camera)",
                       claims=lambda source: source == "synthetic", open=open_synthetic)
"""The entry point's object."""
