"""Scene files (TOML): where home is, how big the ground is, where red objects and ArUco
targets lie (local ENU metres around home), and the default flight altitude and camera.

``load_scene("demo")`` loads the bundled ``demo.toml``; any other argument is a path.
Errors name the file, the key and what was expected. The format itself is
:mod:`utility_specs.scene` (the ground station's map reads it too); this package adds the
bundled scenes and re-exports the format's names.
"""

from __future__ import annotations

from pathlib import Path

from utility_specs.files import read_scene
from utility_specs.scene import CameraSpec, RedObject, Scene, SceneError, Target

__all__ = ["CameraSpec", "RedObject", "Scene", "SceneError", "Target", "load_scene",
           "scene_path"]

SCENES_DIR = Path(__file__).resolve().parent


def scene_path(name_or_path: str | Path) -> Path:
    """A bundled scene by name (``demo``) or a file path."""
    p = Path(name_or_path)
    if p.suffix != ".toml" and not p.exists():
        bundled = SCENES_DIR / f"{name_or_path}.toml"
        if bundled.exists():
            return bundled
    return p


def load_scene(name_or_path: str | Path) -> Scene:
    """A bundled scene by name (``demo``) or the scene file at a path."""
    return read_scene(scene_path(name_or_path))
