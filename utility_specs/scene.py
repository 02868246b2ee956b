"""The scene file format (TOML): where home is, how big the ground is, where red objects
and ArUco targets lie (local ENU metres around home), the default altitude and camera.

The simulator flies and films a scene; the ground station's map draws the same file. Both
read it through here (the bottom layer: no simulator import in the ground station). Pure:
:func:`parse_scene` takes the text; :func:`utility_specs.files.read_scene` reads the file.
Errors name the file, the key and what was expected.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from utility_specs.geo import GeoPoint

__all__ = ["CameraSpec", "RedObject", "Scene", "SceneError", "Target", "parse_scene"]


class SceneError(ValueError):
    """A scene file that cannot be used; the message names the file and key."""


@dataclass(frozen=True, slots=True, kw_only=True)
class RedObject:
    """A red thing on the ground: a disc (``radius_m``) or a box (``width_m`` x ``length_m``)."""

    east_m: float
    north_m: float
    shape: str = "disc"
    radius_m: float = 2.0
    width_m: float = 2.0
    length_m: float = 4.0
    heading_deg: float = 0.0
    bgr: tuple[int, int, int] = (30, 30, 200)


@dataclass(frozen=True, slots=True, kw_only=True)
class Target:
    """An ArUco marker (cv2.aruco DICT_4X4_50) lying flat on the ground, ``size_m`` wide."""

    id: int
    east_m: float
    north_m: float
    size_m: float = 3.0
    heading_deg: float = 0.0
    name: str = ""


@dataclass(frozen=True, slots=True, kw_only=True)
class CameraSpec:
    width_px: int = 640
    height_px: int = 480
    hfov_deg: float = 70.0
    mount_pitch_deg: float = -90.0
    fps: float = 5.0


@dataclass(frozen=True, slots=True, kw_only=True)
class Scene:
    name: str
    home: GeoPoint
    width_m: float = 300.0
    height_m: float = 300.0
    px_per_m: float = 8.0
    default_alt_m: float = 30.0
    seed: int = 0
    red_objects: tuple[RedObject, ...] = ()
    targets: tuple[Target, ...] = ()
    camera: CameraSpec = field(default_factory=CameraSpec)
    path: Path | None = None


def _num(table: dict[str, Any], key: str, where: str, default: float | None = None,
         *, positive: bool = False) -> float:
    value = table.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(
            value):
        raise SceneError(f"{where}.{key}: expected a number, got {value!r}")
    if positive and value <= 0:
        raise SceneError(f"{where}.{key}: expected a positive number, got {value!r}")
    return float(value)


def parse_scene(text: str, path: Path) -> Scene:
    """A scene from the TOML text of the file at ``path`` (named in every error)."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{path}: not valid TOML ({exc})") from exc
    except RecursionError:
        raise SceneError(f"{path}: not valid TOML (nested too deeply)") from None
    f = str(path)
    home_t = data.get("home")
    if not isinstance(home_t, dict):
        raise SceneError(f"{f}: [home] with lat_deg, lon_deg, alt_m is required")
    try:
        home = GeoPoint(lat_deg=_num(home_t, "lat_deg", f"{f}: home"),
                        lon_deg=_num(home_t, "lon_deg", f"{f}: home"),
                        alt_m=_num(home_t, "alt_m", f"{f}: home", 0.0))
    except ValueError as exc:
        raise SceneError(f"{f}: home: {exc}") from exc
    ground = data.get("ground", {})
    flight = data.get("flight", {})
    cam = data.get("camera", {})
    reds = []
    for i, r in enumerate(data.get("red_objects", [])):
        where = f"{f}: red_objects[{i}]"
        shape = r.get("shape", "disc")
        if shape not in ("disc", "box"):
            raise SceneError(f"{where}.shape: expected 'disc' or 'box', got {shape!r}")
        reds.append(RedObject(
            east_m=_num(r, "east_m", where), north_m=_num(r, "north_m", where), shape=shape,
            radius_m=_num(r, "radius_m", where, 2.0, positive=True),
            width_m=_num(r, "width_m", where, 2.0, positive=True),
            length_m=_num(r, "length_m", where, 4.0, positive=True),
            heading_deg=_num(r, "heading_deg", where, 0.0)))
    targets = []
    for i, t in enumerate(data.get("targets", [])):
        where = f"{f}: targets[{i}]"
        tid = t.get("id")
        if not isinstance(tid, int) or not 0 <= tid < 50:
            raise SceneError(f"{where}.id: expected an ArUco DICT_4X4_50 id 0..49, got {tid!r}")
        targets.append(Target(
            id=tid, east_m=_num(t, "east_m", where), north_m=_num(t, "north_m", where),
            size_m=_num(t, "size_m", where, 3.0, positive=True),
            heading_deg=_num(t, "heading_deg", where, 0.0), name=str(t.get("name", ""))))
    return Scene(
        name=str(data.get("name", path.stem)),
        home=home,
        width_m=_num(ground, "width_m", f"{f}: ground", 300.0, positive=True),
        height_m=_num(ground, "height_m", f"{f}: ground", 300.0, positive=True),
        px_per_m=_num(ground, "px_per_m", f"{f}: ground", 8.0, positive=True),
        seed=int(ground.get("seed", 0)),
        default_alt_m=_num(flight, "default_alt_m", f"{f}: flight", 30.0, positive=True),
        red_objects=tuple(reds),
        targets=tuple(targets),
        camera=CameraSpec(
            width_px=int(_num(cam, "width_px", f"{f}: camera", 640, positive=True)),
            height_px=int(_num(cam, "height_px", f"{f}: camera", 480, positive=True)),
            hfov_deg=_num(cam, "hfov_deg", f"{f}: camera", 70.0, positive=True),
            mount_pitch_deg=_num(cam, "mount_pitch_deg", f"{f}: camera", -90.0),
            fps=_num(cam, "fps", f"{f}: camera", 5.0, positive=True)),
        path=path,
    )
