"""The mission area for the dashboard map: a scene file (the one ``uav-sitl`` flies, or one
written for a real field) as plain JSON in local east/north metres around its home.

The map then shows the area outline, the red objects and ArUco targets and home, and every
drone's position in the same frame (``FleetView`` takes home as its origin). The format is
:mod:`utility_specs.scene`, the one the simulator reads (no import of ``sitl`` here).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from utility_specs.files import read_scene
from utility_specs.scene import SceneError

__all__ = ["SceneMapError", "load_scene_map"]


class SceneMapError(ValueError):
    """A scene the map cannot use; the message names the file and the problem."""


def load_scene_map(path: Path) -> dict[str, Any]:
    try:
        scene = read_scene(path)
    except SceneError as exc:
        raise SceneMapError(str(exc)) from None
    half_w, half_h = scene.width_m / 2, scene.height_m / 2
    return {
        "name": scene.name,
        "home": {"lat_deg": scene.home.lat_deg, "lon_deg": scene.home.lon_deg},
        "area": {"west_m": -half_w, "east_m": half_w, "south_m": -half_h, "north_m": half_h},
        "red_objects": [
            {"east_m": r.east_m, "north_m": r.north_m, "shape": r.shape, "radius_m": r.radius_m,
             "width_m": r.width_m, "length_m": r.length_m, "heading_deg": r.heading_deg}
            for r in scene.red_objects
        ],
        "targets": [
            {"id": t.id, "name": t.name, "east_m": t.east_m, "north_m": t.north_m,
             "size_m": t.size_m}
            for t in scene.targets
        ],
    }
