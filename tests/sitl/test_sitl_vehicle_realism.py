"""The built-in vehicle behaves like real ArduCopter 4.5 / PX4 where the companion cares (issue
17): a boot without a fix, the auxiliary commands, parameters, streams, PX4 takeoff semantics
and a listener that only listens. Sans-I/O core against an in-memory GCS, explicit time."""

from __future__ import annotations

import asyncio
import math
import struct
from collections.abc import Callable

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sitl.vehicle.core import DEFAULT_FIRST_FIX_S, DEFAULT_HOME, VehicleConfig
from sitl.vehicle.flavour import ARDUPILOT, PX4, Mode
from sitl.vehicle.shell import start_vehicles

M = mavlink
GPS_BIT = M.MAV_SYS_STATUS_SENSOR_GPS
PREARM_BIT = M.MAV_SYS_STATUS_PREARM_CHECK
EKF_POSITION = M.EKF_POS_HORIZ_ABS | M.EKF_POS_HORIZ_REL


def _ardupilot_streams(gcs, rate_hz: int = 2) -> None:
    gcs.send(M.MAVLink_request_data_stream_message(1, 1, M.MAV_DATA_STREAM_ALL, rate_hz, 1))


def _texts(gcs) -> list[str]:
    return [t.text for t in gcs.of_type("STATUSTEXT")]


# ----------------------------------------------------------------------- boot without a fix


def test_default_first_fix_is_ardupilot_like():
    assert 10.0 <= DEFAULT_FIRST_FIX_S <= 20.0
    assert VehicleConfig().first_fix_s == DEFAULT_FIRST_FIX_S
    with pytest.raises(ValueError, match="first_fix_s"):
        VehicleConfig(first_fix_s=-1.0)


def test_ardupilot_before_its_fix_reports_no_position_and_refuses_to_arm(make_gcs):
    gcs = make_gcs(flavour=ARDUPILOT, first_fix_s=12.0)
    _ardupilot_streams(gcs)
    gcs.run_until(2.0)  # the GPS has no fix yet (it gets one at 0.2 x 12 s)
    gps = gcs.of_type("GPS_RAW_INT")
    assert gps and all(g.fix_type <= 1 and (g.lat, g.lon) == (0, 0) for g in gps)
    pos = gcs.of_type("GLOBAL_POSITION_INT")
    assert pos and all((p.lat, p.lon) == (0, 0) for p in pos)
    status = gcs.of_type("SYS_STATUS")
    assert all(not s.onboard_control_sensors_health & GPS_BIT for s in status)
    early_texts = _texts(gcs)
    gcs.clear()
    gcs.run_until(11.0)
    # As ArduCopter 4.5 SITL (measured): the GPS's 3D fix and its position in
    # GLOBAL_POSITION_INT long before the EKF has an origin and uses it.
    assert gcs.of_type("GPS_RAW_INT")[-1].fix_type == 3
    assert abs(gcs.of_type("GLOBAL_POSITION_INT")[-1].lat / 1e7 - DEFAULT_HOME.lat_deg) < 1e-4
    ekf = gcs.of_type("EKF_STATUS_REPORT")
    assert ekf and all(not e.flags & EKF_POSITION for e in ekf)
    # 167: attitude, velocities, vertical position, constant-position mode (what a real
    # ArduCopter reports without horizontal position).
    assert {e.flags for e in ekf} == {167}
    status = gcs.of_type("SYS_STATUS")
    assert status and all(s.onboard_control_sensors_present & GPS_BIT for s in status)
    assert all(s.onboard_control_sensors_health & GPS_BIT for s in status)
    assert all(not s.onboard_control_sensors_health & PREARM_BIT for s in status)
    assert not gcs.of_type("HOME_POSITION") and not gcs.of_type("GPS_GLOBAL_ORIGIN")
    assert gcs.command(M.MAV_CMD_GET_HOME_POSITION).result == M.MAV_RESULT_FAILED
    assert gcs.command(M.MAV_CMD_REQUEST_MESSAGE, 242).result == M.MAV_RESULT_FAILED
    # Failing pre-arm checks are reported while disarmed (at 2 s, then every 30 s)...
    assert early_texts + _texts(gcs) == ["PreArm: AHRS: waiting for home"]
    # ...and an arm command runs them again, with ArduPilot's "Arm:" prefix.
    ack = gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert ack.result == M.MAV_RESULT_FAILED
    assert _texts(gcs)[-1] == "Arm: AHRS: waiting for home"  # STABILIZE
    gcs.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4)  # GUIDED
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_FAILED
    assert _texts(gcs)[-1] == "Arm: Need Position Estimate"
    assert not gcs.core.fc.state.armed
    assert gcs.command(M.MAV_CMD_DO_SET_HOME, 1).result == M.MAV_RESULT_FAILED

    gcs.clear()
    gcs.run_until(13.0)
    # Home and origin are announced unasked, once, when the estimator gets its origin.
    assert len(gcs.of_type("HOME_POSITION")) == 1
    assert len(gcs.of_type("GPS_GLOBAL_ORIGIN")) == 1
    home = gcs.of_type("HOME_POSITION")[0]
    assert (home.latitude, home.longitude) == (round(DEFAULT_HOME.lat_deg * 1e7),
                                               round(DEFAULT_HOME.lon_deg * 1e7))
    assert "EKF3 IMU0 origin set" in _texts(gcs)
    assert gcs.of_type("GPS_RAW_INT")[-1].fix_type == 3
    assert abs(gcs.of_type("GLOBAL_POSITION_INT")[-1].lat / 1e7 - DEFAULT_HOME.lat_deg) < 1e-4
    assert gcs.of_type("EKF_STATUS_REPORT")[-1].flags & EKF_POSITION == EKF_POSITION
    health = gcs.of_type("SYS_STATUS")[-1].onboard_control_sensors_health
    assert health & GPS_BIT and health & PREARM_BIT
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED


def test_px4_before_its_fix_sends_no_global_position_and_refuses_to_arm(make_gcs):
    gcs = make_gcs(flavour=PX4, first_fix_s=5.0)
    gcs.run_until(4.5)
    assert not gcs.of_type("GLOBAL_POSITION_INT") and not gcs.of_type("HOME_POSITION")
    assert all(g.fix_type <= 1 and g.lat == 0 for g in gcs.of_type("GPS_RAW_INT"))
    est = gcs.of_type("ESTIMATOR_STATUS")
    assert est and all(not e.flags & EKF_POSITION for e in est)
    ack = gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert ack.result == M.MAV_RESULT_TEMPORARILY_REJECTED  # PX4 commander's answer
    # (51 characters: the 50 of one STATUSTEXT arrive)
    assert _texts(gcs)[-1] == "Navigation error: No valid global position estimate"[:50]
    ack = gcs.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, math.nan)
    assert ack.result == M.MAV_RESULT_TEMPORARILY_REJECTED
    assert _texts(gcs)[-1] == "Takeoff denied! Please disarm and retry"
    gcs.clear()
    gcs.run_until(6.0)
    assert gcs.of_type("GLOBAL_POSITION_INT") and gcs.of_type("HOME_POSITION")
    assert gcs.of_type("ESTIMATOR_STATUS")[-1].flags & EKF_POSITION == EKF_POSITION
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED


def test_px4_estimator_flags_are_those_of_px4_sih(make_gcs):
    """As PX4 SIH reports them (measured, docs/sitl.md): 229 before the GNSS is fused, 1023 at
    rest on the ground (CONST_POS_MODE with an absolute position: ekf2 sets it whenever the
    vehicle is at rest), 895 once armed and in the air. A client that takes CONST_POS_MODE
    for "no GPS" (ArduPilot's meaning) never sees a PX4 position on the ground."""
    gcs = make_gcs(flavour=PX4, first_fix_s=3.0)
    gcs.run_until(2.5)
    assert {e.flags for e in gcs.of_type("ESTIMATOR_STATUS")} == {229}
    gcs.clear()
    gcs.run_until(5.0)
    assert gcs.of_type("ESTIMATOR_STATUS")[-1].flags == 1023
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
    gcs.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, math.nan)
    gcs.clear()
    gcs.run_until(12.0)
    assert gcs.of_type("ESTIMATOR_STATUS")[-1].flags == 895


def test_autostart_waits_for_the_fix(make_gcs):
    from sitl.vehicle.mission import MissionItem

    mission = (MissionItem(seq=0, frame=3, command=22, z_m=10.0),
               MissionItem(seq=1, frame=3, command=16, lat_deg=DEFAULT_HOME.lat_deg + 1e-4,
                           lon_deg=DEFAULT_HOME.lon_deg, z_m=10.0))
    gcs = make_gcs(flavour=PX4, first_fix_s=3.0, mission=mission, autostart=True)
    gcs.run_until(2.9)
    assert not gcs.core.fc.state.armed
    gcs.run_until(3.5)
    assert gcs.core.fc.state.armed and gcs.core.fc.mode is Mode.MISSION


# ------------------------------------------------------------------------------ commands


def _ardupilot_flying(make_gcs, alt_m: float = 10.0):
    gcs = make_gcs(flavour=ARDUPILOT)
    _ardupilot_streams(gcs, 4)
    gcs.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4)
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
    assert gcs.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, alt_m).result == 0
    gcs.run_until(20.0)
    assert gcs.core.fc.state.alt_m == pytest.approx(alt_m, abs=0.5)
    return gcs


def test_ardupilot_accepts_servo_relay_camera_and_fence_commands(make_gcs):
    gcs = make_gcs(flavour=ARDUPILOT)
    _ardupilot_streams(gcs, 4)
    assert gcs.command(M.MAV_CMD_DO_SET_SERVO, 9, 1700).result == M.MAV_RESULT_ACCEPTED
    gcs.clear()
    gcs.run_until(gcs.now + 1.0)
    assert gcs.of_type("SERVO_OUTPUT_RAW")[-1].servo9_raw == 1700
    # A motor channel belongs to the motors: refused with ArduPilot's words.
    assert gcs.command(M.MAV_CMD_DO_SET_SERVO, 1, 1700).result == M.MAV_RESULT_FAILED
    assert _texts(gcs)[-1] == "ServoRelayEvent: Channel 1 is already in use"
    assert gcs.command(M.MAV_CMD_DO_SET_RELAY, 0, 1).result == M.MAV_RESULT_ACCEPTED
    assert gcs.core.fc.relays == {0: True}
    # Relay 2 has no function (RELAY2_FUNCTION 0), so it does not switch.
    assert gcs.command(M.MAV_CMD_DO_SET_RELAY, 1, 1).result == M.MAV_RESULT_FAILED
    assert gcs.command(M.MAV_CMD_DO_DIGICAM_CONTROL, 0, 0, 0, 0, 1).result == 0
    assert gcs.core.fc.camera_triggers == 1
    gcs.clear()
    gcs.run_until(gcs.now + 1.0)
    assert not gcs.of_type("FENCE_STATUS")  # streamed only while a fence is enabled
    assert gcs.command(M.MAV_CMD_DO_FENCE_ENABLE, 1).result == M.MAV_RESULT_ACCEPTED
    assert gcs.core.params.get("FENCE_ENABLE") == 1.0
    gcs.run_until(gcs.now + 1.0)
    assert gcs.of_type("FENCE_STATUS")
    assert gcs.command(M.MAV_CMD_DO_FENCE_ENABLE, 7).result == M.MAV_RESULT_FAILED


def test_ardupilot_condition_yaw_turns_the_nose_in_guided(make_gcs):
    gcs = _ardupilot_flying(make_gcs)
    assert gcs.command(M.MAV_CMD_CONDITION_YAW, 90, 30, 1, 0).result == M.MAV_RESULT_ACCEPTED
    gcs.run_until(gcs.now + 8.0)
    assert math.degrees(gcs.core.fc.state.yaw_rad) == pytest.approx(90.0, abs=3.0)
    assert gcs.of_type("GLOBAL_POSITION_INT")[-1].hdg == pytest.approx(9000, abs=300)
    # Relative, counter-clockwise: 90 - 45.
    assert gcs.command(M.MAV_CMD_CONDITION_YAW, 45, 30, -1, 1).result == 0
    gcs.run_until(gcs.now + 8.0)
    assert math.degrees(gcs.core.fc.state.yaw_rad) == pytest.approx(45.0, abs=3.0)
    assert gcs.command(M.MAV_CMD_CONDITION_YAW, 400, 30, 1, 0).result == M.MAV_RESULT_FAILED


def test_do_set_home_moves_home_and_rtl_returns_there(make_gcs):
    gcs = _ardupilot_flying(make_gcs)
    new_lat = DEFAULT_HOME.lat_deg + 20.0 / 111_195.0
    gcs.clear()
    ack = gcs.command(M.MAV_CMD_DO_SET_HOME, 0, 0, 0, 0, new_lat, DEFAULT_HOME.lon_deg,
                      DEFAULT_HOME.alt_m)
    assert ack.result == M.MAV_RESULT_ACCEPTED
    home = gcs.of_type("HOME_POSITION")[-1]
    assert home.latitude == pytest.approx(new_lat * 1e7, abs=10)  # 1e-7 deg is 1.1 cm
    assert home.longitude == pytest.approx(DEFAULT_HOME.lon_deg * 1e7, abs=10)
    gcs.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6)  # RTL
    gcs.run_until(gcs.now + 60.0, stop=lambda: not gcs.core.fc.state.armed)
    assert not gcs.core.fc.state.armed
    assert gcs.core.fc.state.position_ned_m[0] == pytest.approx(20.0, abs=1.5)


def test_px4_accepts_only_the_commands_px4_handles(make_gcs):
    gcs = make_gcs(flavour=PX4)
    assert gcs.command(M.MAV_CMD_DO_SET_HOME, 1).result == M.MAV_RESULT_ACCEPTED
    assert gcs.command(M.MAV_CMD_DO_DIGICAM_CONTROL, 0, 0, 0, 0, 1).result == 0
    for cmd in (M.MAV_CMD_DO_SET_SERVO, M.MAV_CMD_DO_SET_RELAY, M.MAV_CMD_CONDITION_YAW,
                M.MAV_CMD_DO_FENCE_ENABLE):
        assert gcs.command(cmd, 1, 1500).result == M.MAV_RESULT_UNSUPPORTED


# ---------------------------------------------------------------------------- parameters


@pytest.mark.parametrize(("flavour", "names"), [
    (ARDUPILOT, ["BATT_LOW_VOLT", "FENCE_ENABLE", "SR0_EXTRA3", "SR2_POSITION", "ARMING_CHECK",
                 "SYSID_THISMAV", "SERVO9_FUNCTION", "RC3_MIN"]),
    (PX4, ["MAV_SYS_ID", "COM_ARM_WO_GPS", "GF_ACTION", "BAT_LOW_THR", "EKF2_GPS_CTRL",
           "PWM_MAIN_FUNC1", "RC18_TRIM"]),
])
def test_a_realistic_parameter_set(make_gcs, flavour, names):
    gcs = make_gcs(flavour=flavour)
    assert len(gcs.core.params) >= 250
    assert len(set(gcs.core.params.names)) == len(gcs.core.params)
    for name in names:
        gcs.send(M.MAVLink_param_request_read_message(1, 1, name.encode(), -1))
        value = gcs.of_type("PARAM_VALUE")[-1]
        assert value.param_id == name
    gcs.send(M.MAVLink_param_request_read_message(1, 1, b"BATT_LOW_VOLT", -1))
    if flavour is ARDUPILOT:
        assert gcs.of_type("PARAM_VALUE")[-1].param_value == pytest.approx(10.5)


def test_unknown_parameters_are_answered_as_each_stack_does(make_gcs):
    # ArduPilot 4.5 (GCS_Param.cpp): an unknown name or index is dropped without a reply.
    ap = make_gcs(flavour=ARDUPILOT)
    ap.clear()
    ap.send(M.MAVLink_param_request_read_message(1, 1, b"NO_SUCH_PARAM", -1))
    ap.send(M.MAVLink_param_request_read_message(1, 1, b"", 5000))
    ap.send(M.MAVLink_param_set_message(1, 1, b"NO_SUCH_PARAM", 1.0, 9))
    assert ap.received == []
    # PX4 (mavlink_parameters.cpp since v1.14: PX4_ERR, its console only; PX4 SIH sent
    # nothing in 3 s, measured): the same.
    px4 = make_gcs(flavour=PX4)
    px4.clear()
    px4.send(M.MAVLink_param_request_read_message(1, 1, b"NO_SUCH_PARAM", -1))
    px4.send(M.MAVLink_param_request_read_message(1, 1, b"", 5000))
    px4.send(M.MAVLink_param_set_message(1, 1, b"NO_SUCH_PARAM", 1.0, 9))
    assert px4.received == []


# ------------------------------------------------------------------------------- streams


def test_ardupilot_all_streams_carry_what_arducopter_streams(make_gcs):
    gcs = make_gcs(flavour=ARDUPILOT)
    _ardupilot_streams(gcs, 2)
    gcs.run_until(3.0)
    kinds = {m.get_type() for m in gcs.received}
    assert {"EKF_STATUS_REPORT", "NAV_CONTROLLER_OUTPUT", "RC_CHANNELS", "SERVO_OUTPUT_RAW",
            "WIND", "VIBRATION", "AHRS", "AHRS2", "POWER_STATUS", "MEMINFO", "RAW_IMU",
            "SCALED_PRESSURE", "SYS_STATUS", "GPS_RAW_INT", "MISSION_CURRENT", "VFR_HUD",
            "GLOBAL_POSITION_INT", "LOCAL_POSITION_NED", "ATTITUDE", "SYSTEM_TIME",
            "BATTERY_STATUS", "EXTENDED_SYS_STATE"} <= kinds
    assert len(kinds) >= 23
    # Any one of them by SET_MESSAGE_INTERVAL too.
    gcs2 = make_gcs(flavour=ARDUPILOT)
    assert gcs2.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, 193, 500_000).result == 0
    gcs2.clear()
    gcs2.run_until(2.0)
    assert {m.get_type() for m in gcs2.received} == {"HEARTBEAT", "EKF_STATUS_REPORT"}
    assert len(gcs2.of_type("EKF_STATUS_REPORT")) in (4, 5)


def test_wind_reports_where_it_blows_from(make_gcs):
    gcs = make_gcs(flavour=ARDUPILOT, params={"SIM_WIND_SPD": 5.0, "SIM_WIND_DIR": 270.0},
                   gust_fraction=0.0)
    assert gcs.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, 168, 500_000).result == 0
    gcs.run_until(2.0)
    wind = gcs.of_type("WIND")[-1]
    assert wind.speed == pytest.approx(5.0, abs=0.01)
    assert wind.direction == pytest.approx(270.0, abs=0.5)


def test_px4_streams_its_health_and_rc_unrequested(make_gcs):
    gcs = make_gcs(flavour=PX4)
    gcs.run_until(3.0)
    kinds = {m.get_type() for m in gcs.received}
    assert {"ESTIMATOR_STATUS", "RC_CHANNELS", "SERVO_OUTPUT_RAW", "NAV_CONTROLLER_OUTPUT",
            "VIBRATION"} <= kinds
    assert not kinds & {"EKF_STATUS_REPORT", "WIND", "AHRS", "MEMINFO"}  # ArduPilot's own


# ------------------------------------------------------------------------- PX4 takeoff


def test_px4_takeoff_while_disarmed_climbs_once_armed(make_gcs):
    gcs = make_gcs(flavour=PX4)
    ack = gcs.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan,
                      DEFAULT_HOME.alt_m + 8.0)
    assert ack.result == M.MAV_RESULT_ACCEPTED
    assert gcs.core.fc.mode is Mode.TAKEOFF and not gcs.core.fc.state.armed
    hb = gcs.of_type("HEARTBEAT")[-1]
    assert hb.custom_mode == (4 << 16) | (2 << 24)  # AUTO.TAKEOFF
    gcs.run_until(2.0)
    assert gcs.core.fc.state.on_ground
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
    gcs.run_until(20.0)
    assert gcs.core.fc.state.alt_m == pytest.approx(8.0, abs=0.4)
    assert gcs.core.fc.mode is Mode.HOLD


@pytest.mark.parametrize("asked_m", [0.5, 1.0, 2.0])
def test_px4_low_takeoff_uses_mis_takeoff_alt(make_gcs, asked_m):
    gcs = make_gcs(flavour=PX4)
    gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    ack = gcs.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan,
                      DEFAULT_HOME.alt_m + asked_m)
    assert ack.result == M.MAV_RESULT_ACCEPTED
    assert "Using minimum takeoff altitude: 2.50 m" in _texts(gcs)
    gcs.run_until(15.0)
    assert gcs.core.fc.state.alt_m == pytest.approx(2.5, abs=0.3)


# ----------------------------------------------------------------------- passive listener


async def test_a_quiet_listener_keeps_its_stream_while_another_client_talks():
    """A peer heard once keeps receiving (ArduPilot streams per link, whatever the client
    says); the old vehicle dropped peers quiet for 10 s while another talked."""
    [ep] = await start_vehicles([VehicleConfig(flavour=PX4, first_fix_s=0.0)],
                                ports=[0], speedup=1.0)
    loop = asyncio.get_running_loop()
    got: dict[str, list[float]] = {"quiet": [], "talker": []}

    class Client(asyncio.DatagramProtocol):
        def __init__(self, name: str) -> None:
            self.name = name

        def datagram_received(self, data: bytes, addr: object) -> None:
            got[self.name].append(loop.time())

    tx = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    hb = M.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3).pack(tx)
    quiet, _ = await loop.create_datagram_endpoint(lambda: Client("quiet"),
                                                   local_addr=("127.0.0.1", 0))
    talker, _ = await loop.create_datagram_endpoint(lambda: Client("talker"),
                                                    local_addr=("127.0.0.1", 0))
    async def until(condition: Callable[[], bool], what: str) -> None:
        """Wait on the effect, not a fixed time: a loaded CI machine may be slow to get there
        (the vehicle streams several messages a second to every peer it keeps)."""
        deadline = loop.time() + 20.0
        while not condition():
            assert loop.time() < deadline, what
            await asyncio.sleep(0.02)

    try:
        peer = quiet.get_extra_info("sockname")
        quiet.sendto(hb, ep.address)
        await until(lambda: (peer[0], peer[1]) in ep.protocol.peers, "the quiet one unheard")
        # Jump the protocol's idea of when the quiet one was heard 60 s into the past.
        ep.protocol.peers[(peer[0], peer[1])] -= 60.0
        talker_addr = talker.get_extra_info("sockname")
        for _ in range(10):
            talker.sendto(hb, ep.address)
            await asyncio.sleep(0.1)
        await until(lambda: (talker_addr[0], talker_addr[1]) in ep.protocol.peers,
                    "the talker unheard")
        t_check = loop.time()  # the talker has talked: a starving vehicle has dropped the other
        await until(lambda: any(t > t_check for t in got["talker"]), "the talker got nothing")
        await until(lambda: any(t > t_check for t in got["quiet"]),
                    "the quiet listener was starved")
    finally:
        quiet.close()
        talker.close()
        ep.close()


def test_px4_integer_params_stay_bytewise(make_gcs):
    gcs = make_gcs(flavour=PX4)
    gcs.send(M.MAVLink_param_request_read_message(1, 1, b"GF_ACTION", -1))
    value = gcs.of_type("PARAM_VALUE")[-1]
    assert struct.unpack("<i", struct.pack("<f", value.param_value))[0] == 2


# ---------------------------------------------------------------------------------- CLI


def test_cli_first_fix_default_flag_and_bad_value():
    import subprocess
    import sys

    from sitl.vehicle.cli import build_configs, parse_args

    assert build_configs(parse_args([]))[0].first_fix_s == DEFAULT_FIRST_FIX_S
    assert build_configs(parse_args(["--first-fix", "0"]))[0].first_fix_s == 0.0
    auto = build_configs(parse_args(["--pattern", "orbit", "--autostart"]))[0]
    assert auto.autostart and auto.mission
    proc = subprocess.run([sys.executable, "-m", "sitl.cli", "vehicle", "--first-fix", "-1"],
                          capture_output=True, text=True, timeout=30)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines()[-1] == (
        "uav-sitl vehicle: error: --first-fix must be a number of seconds >= 0")
    assert "Traceback" not in proc.stderr


def test_px4_returns_to_the_last_armable_mode_when_it_disarms(make_gcs):
    """PX4 SIH (measured): Hold at boot; landed in LAND after MISSION, it disarmed in
    MISSION, the last mode the user chose that allows arming (commander's
    UserModeIntention); takeoff completion and mission end count as chosen, LAND and RTL not."""
    from sitl.vehicle.mission import MissionItem

    gcs = make_gcs(flavour=PX4)
    gcs.run_until(1.0)
    assert gcs.of_type("HEARTBEAT")[-1].custom_mode == 4 << 16 | 3 << 24  # AUTO.LOITER
    lat, lon = DEFAULT_HOME.lat_deg, DEFAULT_HOME.lon_deg
    gcs.core.fc.set_mission([MissionItem(seq=s, frame=3, command=22, z_m=10.0,
                                         lat_deg=lat + 1e-4 * s, lon_deg=lon) for s in (0, 1)])
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
    gcs.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, math.nan)
    gcs.run_until(10.0)
    assert gcs.command(M.MAV_CMD_DO_SET_MODE, 1, 4, 4).result == M.MAV_RESULT_ACCEPTED
    gcs.run_until(12.0)
    assert gcs.command(M.MAV_CMD_DO_SET_MODE, 1, 4, 6).result == M.MAV_RESULT_ACCEPTED  # LAND
    gcs.run_until(40.0)
    hb = gcs.of_type("HEARTBEAT")[-1]
    assert not hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED
    assert hb.custom_mode == 4 << 16 | 4 << 24  # AUTO.MISSION, as PX4 SIH
