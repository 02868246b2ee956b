"""The scene file format in the bottom layer (issue 14): the ground station's map and the
simulator read one format, and reading a scene for the map loads no simulator code."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from sitl.scenes import load_scene, scene_path
from utility_specs.files import read_scene
from utility_specs.geo import GeoPoint
from utility_specs.scene import SceneError, parse_scene

ROOT = Path(__file__).resolve().parents[2]

SMALL = """
name = "field"
[home]
lat_deg = 47.5
lon_deg = 8.25
[ground]
width_m = 120
[[red_objects]]
east_m = 10
north_m = -5
shape = "box"
[[targets]]
id = 7
east_m = -3
north_m = 4
"""


def test_parse_scene_reads_the_values_and_defaults() -> None:
    scene = parse_scene(SMALL, Path("field.toml"))
    assert scene.name == "field"
    assert scene.home == GeoPoint(lat_deg=47.5, lon_deg=8.25, alt_m=0.0)
    assert (scene.width_m, scene.height_m) == (120.0, 300.0)
    assert [(r.east_m, r.north_m, r.shape) for r in scene.red_objects] == [(10.0, -5.0, "box")]
    assert [(t.id, t.east_m, t.north_m, t.size_m) for t in scene.targets] == [(7, -3.0, 4.0, 3.0)]
    assert scene.path == Path("field.toml")


def test_the_simulator_and_the_format_read_the_bundled_scene_alike() -> None:
    assert read_scene(scene_path("demo")) == load_scene("demo")


@pytest.mark.parametrize(("text", "error"), [
    ("[home\n", "field.toml: not valid TOML"),
    ("name = 'x'\n", "field.toml: [home] with lat_deg, lon_deg, alt_m is required"),
    ("[home]\nlat_deg = 91\nlon_deg = 0\n", "field.toml: home: lat_deg must be in [-90, 90]"),
])
def test_a_bad_scene_names_the_file_and_the_problem(text: str, error: str) -> None:
    with pytest.raises(SceneError) as info:
        parse_scene(text, Path("field.toml"))
    assert str(info.value).startswith(error)


def test_read_scene_of_a_missing_file_is_a_scene_error(tmp_path: Path) -> None:
    with pytest.raises(SceneError, match=r"missing\.toml: cannot read scene"):
        read_scene(tmp_path / "missing.toml")


def test_the_dashboard_map_loads_no_simulator_module() -> None:
    code = (
        "import sys\n"
        "from pathlib import Path\n"
        "from ground_station.scene_map import load_scene_map\n"
        f"m = load_scene_map(Path({str(scene_path('demo'))!r}))\n"
        "assert m['targets'], m\n"
        "print(sorted(n for n in sys.modules if n == 'sitl' or n.startswith('sitl.')))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, timeout=60, check=True)
    assert out.stdout.strip() == "[]"
