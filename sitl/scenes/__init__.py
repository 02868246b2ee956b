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

__all__ = ["CameraSpec", "RedObject", "Scene", "SceneError", "Target", "bundled_scenes",
           "load_scene", "scene_path"]

SCENES_DIR = Path(__file__).resolve().parent


def scene_path(name_or_path: str | Path) -> Path:
    """A bundled scene by name (``demo``) or a file path."""
    p = Path(name_or_path)
    if p.suffix != ".toml" and not p.exists():
        bundled = SCENES_DIR / f"{name_or_path}.toml"
        if bundled.exists():
            return bundled
    return p


def bundled_scenes() -> list[str]:
    """Names of the scenes shipped with the package (``demo``...)."""
    return sorted(path.stem for path in SCENES_DIR.glob("*.toml"))


def load_scene(name_or_path: str | Path) -> Scene:
    """A bundled scene by name (``demo``) or the scene file at a path. A name that is
    neither says which names there are (``--scene dmeo`` read as a missing file)."""
    path = scene_path(name_or_path)
    if path.suffix != ".toml" and not path.exists():
        raise SceneError(f"no scene {str(name_or_path)!r}: not a bundled scene "
                         f"({', '.join(bundled_scenes())}) nor a file")
    return read_scene(path)
