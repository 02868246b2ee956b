"""The model's file edge: mission specs, logs and scene files read from disk.

Everything else in utility_specs is pure and takes parsed data (:func:`parse_spec`,
:func:`parse_log`, :func:`~utility_specs.scene.parse_scene`); these loaders only read a file
and hand its text on.
"""

from __future__ import annotations

import tomllib
from importlib import resources
from pathlib import Path

from utility_specs.errors import LogError, SpecError
from utility_specs.log import MissionLog, parse_log
from utility_specs.scene import Scene, SceneError, parse_scene
from utility_specs.spec import MissionSpec, parse_spec

__all__ = ["builtin_spec", "builtin_specs", "load_spec", "read_log", "read_scene", "spec_named"]


def read_log(path: str | Path) -> MissionLog:
    """Parse a mission log file; a torn last line (writer stopped mid-line) is forgiven."""
    path = Path(path)
    try:
        with path.open(encoding="utf-8") as f:
            return parse_log(f, source=str(path), allow_torn_tail=True)
    except FileNotFoundError:
        raise LogError(f"{path}: no such log file") from None
    except UnicodeDecodeError as exc:
        raise LogError(f"{path}: not a text file (byte {exc.start} is not UTF-8); expected "
                       "JSON Lines") from None
    except OSError as exc:  # a folder, no permission...
        raise LogError(f"{path}: cannot read ({exc.strerror})") from None


def load_spec(path: str | Path) -> MissionSpec:
    """Read and validate a spec file."""
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise SpecError(f"{path}: no such spec file") from None
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"{path}: not valid TOML ({exc})") from None
    except UnicodeDecodeError as exc:
        raise SpecError(f"{path}: not a text file (byte {exc.start} is not UTF-8)") from None
    except RecursionError:
        raise SpecError(f"{path}: not valid TOML (nested too deeply)") from None
    except OSError as exc:  # a folder, no permission...
        raise SpecError(f"{path}: cannot read ({exc.strerror})") from None
    return parse_spec(raw, source=str(path))


def builtin_specs() -> list[str]:
    """Names of the mission specs shipped in ``utility_specs/missions``."""
    folder = resources.files("utility_specs") / "missions"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def builtin_spec(name: str) -> MissionSpec:
    """A shipped spec by name (``telemetry``, ``image_streaming``...)."""
    resource = resources.files("utility_specs") / "missions" / f"{name}.toml"
    if not resource.is_file():
        raise SpecError(f"no built-in spec {name!r}; expected one of {builtin_specs()}")
    raw = tomllib.loads(resource.read_text(encoding="utf-8"))
    return parse_spec(raw, source=f"utility_specs/missions/{name}.toml")


def spec_named(text: str) -> MissionSpec:
    """``--spec``: a file (``*.toml``, any existing file whatever its suffix, or a path with a
    folder in it) or else a built-in spec's name. An existing ``spec.txt`` was looked up as
    a built-in and refused with "no built-in spec"."""
    path = Path(text)
    if path.suffix == ".toml" or path.exists() or len(path.parts) > 1:
        return load_spec(path)
    return builtin_spec(text)


def read_scene(path: str | Path) -> Scene:
    """Parse the scene file at ``path``; a file that cannot be read is a SceneError too."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise SceneError(f"{path}: cannot read scene ({exc.strerror})") from exc
    except UnicodeDecodeError as exc:
        raise SceneError(f"{path}: not a text file (byte {exc.start} is not UTF-8)") from None
    return parse_scene(text, path)
