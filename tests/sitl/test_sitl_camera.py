"""The synthetic camera: red share, ArUco targets, geometry, lighting, noise, the CLI."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import cv2
import numpy as np
import pytest

from sitl.camera import CameraPose, SyntheticCamera, pose_from_geo
from sitl.geo import Enu, geo_from_enu
from sitl.scenes import load_scene


@pytest.fixture(scope="module")
def scene():
    return load_scene("demo")


@pytest.fixture(scope="module")
def camera(scene):
    return SyntheticCamera(scene, seed=3)


def hsv_red_share(frame: np.ndarray) -> float:
    """Computed here with cv2 directly, both red hue bands, as a scorer would."""
    hsv = cv2.cvtColor(frame, cv2.COLOR_BGR2HSV)
    mask = cv2.inRange(hsv, np.array([0, 100, 50]), np.array([10, 255, 255])) | cv2.inRange(
        hsv, np.array([170, 100, 50]), np.array([180, 255, 255]))
    return float(np.count_nonzero(mask)) / mask.size


def test_frames_are_bgr_uint8_of_the_configured_size(scene):
    cam = SyntheticCamera(scene, width_px=320, height_px=240, seed=0)
    frame = cam.render(CameraPose(east_m=0, north_m=0, up_m=30))
    assert frame.shape == (240, 320, 3) and frame.dtype == np.uint8
    assert frame.flags["C_CONTIGUOUS"]


def test_red_share_rises_when_a_red_object_is_under_the_drone(scene, camera):
    red = scene.red_objects[0]
    bare = hsv_red_share(camera.render(CameraPose(east_m=-60, north_m=-40, up_m=30)))
    over = hsv_red_share(camera.render(CameraPose(east_m=red.east_m, north_m=red.north_m,
                                                  up_m=30)))
    assert bare < 0.001
    # A disc of radius 3 m seen from 30 m with a 70 deg lens: pi r^2 / footprint area.
    footprint_w = 2 * 30 * math.tan(math.radians(35))
    expected = math.pi * red.radius_m**2 / (footprint_w * footprint_w * 480 / 640)
    assert over == pytest.approx(expected, rel=0.2)
    # Lower is bigger: the share grows as the drone descends over it.
    low = hsv_red_share(camera.render(CameraPose(east_m=red.east_m, north_m=red.north_m,
                                                 up_m=15)))
    assert low > 3 * over


def test_aruco_target_is_detected_from_above(scene, camera):
    target = scene.targets[0]
    frame = camera.render(CameraPose(east_m=target.east_m + 3, north_m=target.north_m - 2,
                                     up_m=25, yaw_rad=0.6), t_s=10.0)
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50),
                                       cv2.aruco.DetectorParameters())
    corners, ids, _ = detector.detectMarkers(frame)
    assert ids is not None and ids.ravel().tolist() == [target.id]
    # The detected centre is where the camera model projects the target.
    u, v = camera.project(CameraPose(east_m=target.east_m + 3, north_m=target.north_m - 2,
                                     up_m=25, yaw_rad=0.6), target.east_m, target.north_m)
    centre = corners[0][0].mean(axis=0)
    assert np.hypot(centre[0] - u, centre[1] - v) < 3.0
    away = camera.render(CameraPose(east_m=60, north_m=-60, up_m=25))
    assert detector.detectMarkers(away)[1] is None


def test_north_is_up_at_yaw_zero_and_down_at_yaw_pi(scene, camera):
    red = scene.red_objects[0]
    below = CameraPose(east_m=red.east_m, north_m=red.north_m - 8, up_m=30)
    u, v = camera.project(below, red.east_m, red.north_m)
    assert v < 240 and abs(u - 319.5) < 1  # object to the north: upper half
    turned = CameraPose(east_m=red.east_m, north_m=red.north_m - 8, up_m=30, yaw_rad=math.pi)
    assert camera.project(turned, red.east_m, red.north_m)[1] > 240
    frame = camera.render(below, t_s=0.0)
    assert hsv_red_share(frame[:240]) > 10 * max(hsv_red_share(frame[240:]), 1e-4)


def test_roll_shifts_the_view_unless_the_gimbal_stabilises(scene, camera):
    pose = CameraPose(east_m=0, north_m=0, up_m=30, roll_rad=math.radians(10))
    u_fixed, _ = camera.project(pose, 0.0, 0.0)
    gimbal = SyntheticCamera(scene, gimbal_stabilised=True, texture=camera.texture)
    u_gimbal, _ = gimbal.project(pose, 0.0, 0.0)
    # Rolling right (right side down) tilts the belly, and a fixed nadir camera, to the left:
    # the point below moves right in the image by f tan(10 deg).
    f = camera.K[0, 0]
    assert u_fixed == pytest.approx(319.5 + f * math.tan(math.radians(10)), abs=1e-6)
    assert u_gimbal == pytest.approx(319.5, abs=1e-6)


def test_forward_camera_sees_sky_above_the_horizon(scene):
    cam = SyntheticCamera(scene, mount_pitch_deg=0.0, noise_std=0.0, lighting=False)
    frame = cam.render(CameraPose(east_m=0, north_m=-90, up_m=10))
    top, bottom = frame[:200].reshape(-1, 3).mean(axis=0), frame[-100:].reshape(-1, 3).mean(0)
    assert top[0] > top[1] > top[2]  # blue sky (BGR)
    assert bottom[1] > bottom[0]  # green fields


def test_same_seed_same_frames_lighting_varies_with_time(scene, camera):
    a = SyntheticCamera(scene, seed=9, texture=camera.texture)
    b = SyntheticCamera(scene, seed=9, texture=camera.texture)
    pose = CameraPose(east_m=10, north_m=10, up_m=40)
    fa, fb = a.render(pose, t_s=1.0), b.render(pose, t_s=1.0)
    assert np.array_equal(fa, fb)
    quiet = SyntheticCamera(scene, noise_std=0.0, clouds=False, texture=camera.texture)
    bright = quiet.render(pose, t_s=37.0 / 4).astype(float).mean()
    dark = quiet.render(pose, t_s=3 * 37.0 / 4).astype(float).mean()
    assert bright > 1.15 * dark
    a = SyntheticCamera(scene, seed=9, clouds=False, texture=camera.texture)
    noisy = a.render(pose, t_s=1.0).astype(float) - quiet.render(pose, t_s=1.0).astype(float)
    assert noisy.std() == pytest.approx(3.0, rel=0.25)


def test_high_altitude_uses_a_mip_level_and_still_sees_red(scene, camera):
    pose = CameraPose(east_m=30, north_m=20, up_m=150)
    frame = camera.render(pose)
    share = hsv_red_share(frame)
    visible = camera.visible(pose)["red_objects"]
    assert len(visible) >= 4
    # Looking straight down, the share is the visible red area over the ground footprint.
    half_width = pose.up_m * math.tan(math.radians(scene.camera.hfov_deg) / 2)
    footprint = (2 * half_width) * (2 * half_width * 480 / 640)
    red_area = sum(
        math.pi * o.radius_m**2 if o.shape == "disc" else o.width_m * o.length_m
        for o in (scene.red_objects[i] for i in visible)
    )
    assert share == pytest.approx(red_area / footprint, rel=0.35)


def test_pose_from_geo_matches_the_scene_frame(scene, camera):
    g = geo_from_enu(Enu(east_m=20.0, north_m=30.0), scene.home)
    pose = pose_from_geo(scene.home, lat_deg=g.lat_deg, lon_deg=g.lon_deg, alt_rel_m=30.0)
    assert (pose.east_m, pose.north_m, pose.up_m) == pytest.approx((20.0, 30.0, 30.0), abs=1e-6)
    assert camera.visible(pose)["red_objects"] == [0]


def test_camera_cli_writes_pngs_and_reports_red_share(tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "sitl.cli", "camera", "--scene", "demo", "--pose", "20,30,30",
         "--pose=-60,-40,30,0,0,45", "--size", "320x240", "--out", str(tmp_path)],
        capture_output=True, text=True, timeout=60, check=True)
    rows = [json.loads(line) for line in out.stdout.splitlines()]
    assert [r["file"] for r in rows] == [str(tmp_path / "frame_0000.png"),
                                         str(tmp_path / "frame_0001.png")]
    assert rows[0]["red_share"] > 0.01 > rows[1]["red_share"]
    frame = cv2.imread(rows[0]["file"])
    assert frame.shape == (240, 320, 3)
    assert hsv_red_share(frame) == pytest.approx(rows[0]["red_share"], abs=0.003)


def test_cloud_shadows_darken_part_of_the_view_and_drift(scene, camera):
    sunny = SyntheticCamera(scene, noise_std=0.0, clouds=False, texture=camera.texture)
    cloudy = SyntheticCamera(scene, noise_std=0.0, texture=camera.texture)
    pose = CameraPose(east_m=0, north_m=0, up_m=120)
    def ratio(t_s: float) -> np.ndarray:
        return (cloudy.render(pose, t_s=t_s).astype(float) + 1.0) / (
            sunny.render(pose, t_s=t_s).astype(float) + 1.0)

    ratio0, ratio1 = ratio(5.0), ratio(35.0)
    shaded = ratio0.mean(axis=2) < 0.9
    assert 0.05 < shaded.mean() < 0.7  # some of the ground is under a cloud, not all of it
    assert ratio0.min() > 0.6  # a shadow takes at most 35 % of the light (plus rounding)
    assert (ratio1.mean(axis=2) < 0.9).mean() > 0.05
    assert np.mean(shaded != (ratio1.mean(axis=2) < 0.9)) > 0.02  # 60 m of drift in 30 s
