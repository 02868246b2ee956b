"""Data the dashboard explains itself with (issue 12): the red-border threshold follows the
spec's utility scale, not a fixed 3.0; each gallery image says why it was sent."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from companion.protocol import Encoder
from ground_station.app import create_app
from ground_station.config import ConfigError, GroundConfig, config_from_mapping
from ground_station.keys import STORAGE
from ground_station.scene_map import load_scene_map
from ground_station.utility import ImageUtility, image_utility_from_spec
from tests.ground_station.conftest import KEY, TOKEN, auth
from tests.ground_station.test_gs_app import feed
from tests.ground_station.test_gs_cores import image
from utility_specs.functions import RedImage, Video

SPECS = Path(__file__).resolve().parents[2] / "utility_specs" / "missions"


def test_threshold_is_a_fraction_of_the_specs_gain() -> None:
    streaming = image_utility_from_spec(SPECS / "image_streaming.toml", alpha=3.0)
    assert streaming.max_gain() == 10.0  # the spec's alpha wins over the config's
    assert streaming.high_threshold(0.1) == pytest.approx(2.0)
    assert ImageUtility(alpha=40.0).high_threshold(0.25) == pytest.approx(11.0)
    # only plain video: no image can gain, so none is ever high
    plain = ImageUtility(alpha=10.0, by_type={"video": Video()})
    assert plain.max_gain() == 0.0 and plain.high_threshold(0.1) is None


@given(alpha=st.floats(0.1, 1000.0), fraction=st.floats(0.01, 1.0), red=st.floats(0.0, 1.0))
def test_high_exactly_from_the_fraction_of_red_share(alpha: float, fraction: float,
                                                     red: float) -> None:
    """Under eq. 7.1 an image is high iff its red share reaches the fraction."""
    u = ImageUtility(alpha=alpha, by_type={"image": RedImage(alpha=alpha)})
    threshold = u.high_threshold(fraction)
    assert threshold is not None
    weight = u.weight(image("image", {"red": red}))
    if red >= fraction * (1 + 1e-9):
        assert weight >= threshold
    elif red <= fraction * (1 - 1e-9):
        assert weight < threshold


def test_config_fraction_checked_and_explicit_threshold_kept() -> None:
    with pytest.raises(ConfigError, match="high_utility_fraction"):
        config_from_mapping({"high_utility_fraction": 0})
    with pytest.raises(ConfigError, match="high_utility_fraction"):
        config_from_mapping({"high_utility_fraction": 1.5})
    assert config_from_mapping({"high_utility": 4}).high_utility == 4.0
    assert config_from_mapping({}).high_utility is None


@pytest.mark.parametrize(
    ("changes", "high", "top", "fraction"),
    [
        ({}, 2.0, 11.0, 0.1),  # no spec: the config's alpha 10
        ({"alpha": 30.0, "high_utility_fraction": 0.2}, 7.0, 31.0, 0.2),
        ({"spec": SPECS / "image_streaming.toml", "alpha": 50.0}, 2.0, 11.0, 0.1),
        ({"high_utility": 3.0}, 3.0, 11.0, None),  # an operator's explicit value stays
    ],
)
async def test_snapshot_carries_the_threshold(
    gs_config: GroundConfig, aiohttp_client: Callable[..., Any], changes: dict[str, Any],
    high: float, top: float, fraction: float | None,
) -> None:
    client = await aiohttp_client(create_app(gs_config.with_overrides(**changes), token=TOKEN))
    body = await (await client.get("/api/fleet", headers=auth())).json()
    assert body["config"]["high_utility"] == pytest.approx(high)
    scale = body["config"]["utility_scale"]
    assert scale["max"] == pytest.approx(top) and scale["fraction"] == fraction
    async with client.ws_connect("/ws", headers=auth()) as ws:
        snapshot = await ws.receive_json()
    assert snapshot["config"]["high_utility"] == pytest.approx(high)
    assert snapshot["config"]["utility_scale"] == scale


async def test_gallery_image_says_its_share_of_the_window(
    gs_config: GroundConfig, aiohttp_client: Callable[..., Any]
) -> None:
    """window_share: the sender's bytes among all drones' in the 5 s before it arrived."""
    t = [1_700_000_000.0]
    client = await aiohttp_client(create_app(gs_config, clock=lambda: t[0], token=TOKEN))
    a, b = Encoder(7, "uav1", KEY), Encoder(7, "uav2", KEY)
    feed(client, a, 1, now=t[0], payload=b"a" * 100, red=0.1)       # alone: 100 %
    t[0] += 1.0
    feed(client, b, 1, now=t[0], payload=b"b" * 300, red=0.9)       # 300 of 400
    t[0] += 6.0
    feed(client, b, 2, now=t[0], payload=b"b" * 100, red=0.5)       # the first two are out
    t[0] += 3.0
    feed(client, a, 2, now=t[0], payload=b"a" * 300, red=0.0)       # 300 of 400
    await client.server.app[STORAGE].flush()
    body = await (await client.get("/api/images", headers=auth())).json()
    shares = {(im["sender"], im["seq"]): im["window_share"] for im in body["images"]}
    assert shares == {("uav2", 1): pytest.approx(0.75), ("uav2", 2): pytest.approx(1.0),
                      ("uav1", 1): pytest.approx(1.0), ("uav1", 2): pytest.approx(0.75)}
    assert body["window_s"] == 5.0


def test_scene_map_is_the_scene_in_local_metres() -> None:
    from sitl.scenes import load_scene, scene_path

    scene = load_scene("demo")
    m = load_scene_map(scene_path("demo"))
    assert m["home"] == {"lat_deg": 47.397742, "lon_deg": 8.545594}
    assert m["area"] == {"west_m": -120.0, "east_m": 120.0, "south_m": -100.0, "north_m": 100.0}
    assert [(r["east_m"], r["north_m"]) for r in m["red_objects"]] == [
        (r.east_m, r.north_m) for r in scene.red_objects]
    assert [t["id"] for t in m["targets"]] == [t.id for t in scene.targets]


def test_a_broken_scene_stops_run_with_one_line(tmp_path: Path) -> None:
    station = Path(sys.executable).parent / "uav-ground-station"
    data = tmp_path / "data"
    keygen = subprocess.run([str(station), "keygen", "--data-dir", str(data)],
                            capture_output=True, text=True, timeout=60)
    assert keygen.returncode == 0, keygen.stderr
    (tmp_path / "bad.toml").write_text("name = 'x'\n[ground]\nwidth_m = 10\n")
    config = tmp_path / "gs.toml"
    config.write_text('data_dir = "data"\nscene = "bad.toml"\nhttp_port = 0\nudp_port = 0\n')
    run = subprocess.run([str(station), "run", "--config", str(config)],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2
    assert run.stderr.strip().splitlines() == [
        f"uav-ground-station: scene: {tmp_path / 'bad.toml'}: [home] with lat_deg, lon_deg,"
        " alt_m is required"]
    assert not (data / "token").exists()  # stopped before a token is made and shown
