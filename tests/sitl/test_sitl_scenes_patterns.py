"""Scene files and flight patterns."""

from __future__ import annotations

import math

import pytest

from sitl.geo import GeoPoint, enu_from_geo
from sitl.scenes import SceneError, load_scene
from sitl.vehicle.mission import CMD_CHANGE_SPEED, CMD_RTL, CMD_TAKEOFF, CMD_WAYPOINT
from sitl.vehicle.patterns import PatternError, load_waypoints, orbit, survey

HOME = GeoPoint(lat_deg=47.397742, lon_deg=8.545594, alt_m=488.0)


def _en(item):
    local = enu_from_geo(GeoPoint(lat_deg=item.lat_deg, lon_deg=item.lon_deg, alt_m=HOME.alt_m),
                         HOME)
    return local.east_m, local.north_m


def test_demo_scene_has_red_objects_one_target_and_a_home():
    scene = load_scene("demo")
    assert len(scene.red_objects) >= 3
    assert [t.id for t in scene.targets] == [7]
    assert scene.home.alt_m == 488.0
    # All objects lie on the ground plane.
    for obj in (*scene.red_objects, *scene.targets):
        assert abs(obj.east_m) < scene.width_m / 2 and abs(obj.north_m) < scene.height_m / 2


@pytest.mark.parametrize(("text", "needle"), [
    ("[home]\nlat_deg = 'x'\nlon_deg = 1.0\n", "home.lat_deg: expected a number"),
    ("name = 'x'\n", "[home]"),
    ("[home]\nlat_deg = 1.0\nlon_deg = 2.0\n[[targets]]\nid = 99\neast_m = 0\nnorth_m = 0\n",
     "targets[0].id"),
    ("[home]\nlat_deg = 1.0\nlon_deg = 2.0\n[[red_objects]]\neast_m = 0\nnorth_m = 0\n"
     "shape = 'star'\n", "red_objects[0].shape"),
    ("[home\n", "not valid TOML"),
])
def test_scene_errors_name_the_file_and_key(tmp_path, text, needle):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(SceneError) as err:
        load_scene(path)
    assert needle in str(err.value) and "bad.toml" in str(err.value)


def test_survey_is_a_lawnmower_covering_the_box():
    items = survey(HOME, center_en_m=(30.0, 0.0), width_m=60.0, height_m=100.0, spacing_m=20.0,
                   alt_m=25.0)
    assert [i.command for i in items[:2]] == [CMD_TAKEOFF, CMD_CHANGE_SPEED]
    assert items[-1].command == CMD_RTL
    assert [i.seq for i in items] == list(range(len(items)))
    wps = [_en(i) for i in items if i.command == CMD_WAYPOINT]
    easts = sorted({round(e, 3) for e, _ in wps})
    assert easts == pytest.approx([0.0, 20.0, 40.0, 60.0], abs=1e-3)
    # Legs alternate direction: south->north, then north->south...
    assert [round(n) for _, n in wps] == [-50, 50, 50, -50, -50, 50, 50, -50]
    assert {i.z_m for i in items if i.command == CMD_WAYPOINT} == {25.0}


def test_orbit_points_lie_on_the_circle_and_start_at_the_bearing():
    items = orbit(HOME, center_en_m=(-90.0, 10.0), radius_m=30.0, alt_m=20.0, start_deg=90.0,
                  item0_is_home=True)
    assert items[0].command == CMD_WAYPOINT and items[0].frame == 0  # ArduPilot home slot
    wps = [_en(i) for i in items[1:] if i.command == CMD_WAYPOINT]
    for e, n in wps:
        assert math.hypot(e + 90.0, n - 10.0) == pytest.approx(30.0, abs=0.01)
    assert wps[0] == pytest.approx((-60.0, 10.0), abs=0.01)  # bearing 90 = east of centre
    with pytest.raises(PatternError):
        orbit(HOME, radius_m=0.0, alt_m=10.0)


def test_waypoints_csv_file(tmp_path):
    path = tmp_path / "wp.csv"
    path.write_text("# lat,lon,alt\n47.3980,8.5456,15\n47.3982,8.5460\n")
    items = load_waypoints(path, home=HOME, default_alt_m=30.0)
    wps = [i for i in items if i.command == CMD_WAYPOINT]
    assert [(w.lat_deg, w.z_m) for w in wps] == [(47.3980, 15.0), (47.3982, 30.0)]
    assert items[0].command == CMD_TAKEOFF and items[-1].command == CMD_RTL


def test_waypoints_qgc_wpl_file(tmp_path):
    path = tmp_path / "wp.waypoints"
    path.write_text(
        "QGC WPL 110\n"
        "0\t1\t0\t16\t0\t0\t0\t0\t47.397742\t8.545594\t488.0\t1\n"
        "1\t0\t3\t22\t0\t0\t0\t0\t0\t0\t10.0\t1\n"
        "2\t0\t3\t16\t0\t0\t0\t0\t47.3980\t8.5456\t10.0\t1\n")
    ap = load_waypoints(path, home=HOME, default_alt_m=30.0, item0_is_home=True)
    px4 = load_waypoints(path, home=HOME, default_alt_m=30.0, item0_is_home=False)
    assert [i.command for i in ap] == [16, 22, 16]
    assert [(i.seq, i.command) for i in px4] == [(0, 22), (1, 16)]
    bad = tmp_path / "bad.csv"
    bad.write_text("47.3,notanumber\n")
    with pytest.raises(PatternError, match=r"bad\.csv:1"):
        load_waypoints(bad, home=HOME, default_alt_m=30.0)


@pytest.mark.parametrize("flavour", ["px4", "ardupilot"])
def test_orbit_flown_keeps_the_target_in_a_tilted_cameras_view(flavour):
    from sitl.camera import CameraPose, SyntheticCamera
    from sitl.vehicle.core import VehicleConfig, VehicleCore
    from sitl.vehicle.flavour import FLAVOURS, Mode

    scene = load_scene("demo")
    target = scene.targets[0]
    ap = flavour == "ardupilot"
    mission = orbit(scene.home, center_en_m=(target.east_m, target.north_m), radius_m=20.0,
                    alt_m=25.0, speed_m_s=5.0, item0_is_home=ap)
    core = VehicleCore(VehicleConfig(home=scene.home, mission=tuple(mission),
                                     flavour=FLAVOURS[flavour], first_fix_s=0.0))
    core.fc.arm()
    core.fc.set_mode(Mode.MISSION)
    camera = SyntheticCamera(scene, mount_pitch_deg=-50.0, gimbal_stabilised=True,
                             noise_std=0.0, lighting=False)
    first_wp = 3 + ap  # after (home,) takeoff, speed change and DO_SET_ROI_LOCATION
    last_wp = len(mission) - 3  # before DO_SET_ROI_NONE and RTL
    seen, samples = 0, 0
    now = 0.0
    while now < 400.0 and core.fc.mission_current <= last_wp:
        now += 0.5
        core.handle_timer(now)
        core.datagrams_to_send()
        if first_wp + 1 <= core.fc.mission_current <= last_wp:
            st = core.fc.state
            pose = CameraPose(east_m=st.position_ned_m[1], north_m=st.position_ned_m[0],
                              up_m=st.alt_m, yaw_rad=st.yaw_rad)
            samples += 1
            seen += target.id in camera.visible(pose)["targets"]
    assert samples > 20
    assert seen / samples > 0.9  # nose on the centre: the target stays in view
