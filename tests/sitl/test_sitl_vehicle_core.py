"""The sans-I/O vehicle core against an in-memory GCS, with explicit time."""

from __future__ import annotations

import math
import struct

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl.vehicle.core import DEFAULT_HOME
from sitl.vehicle.flavour import ARDUPILOT, PX4, Mode

M = mavlink


def _px4_mode_params(main: int, sub: int = 0) -> tuple[float, float, float]:
    return (float(M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(main), float(sub))


def test_px4_streams_flow_unrequested_at_their_rates(make_gcs):
    gcs = make_gcs(flavour=PX4)
    gcs.run_until(2.0)
    kinds = {m.get_type() for m in gcs.received}
    assert {"HEARTBEAT", "SYS_STATUS", "BATTERY_STATUS", "GLOBAL_POSITION_INT",
            "LOCAL_POSITION_NED", "ATTITUDE", "GPS_RAW_INT", "HOME_POSITION",
            "EXTENDED_SYS_STATE", "SYSTEM_TIME"} <= kinds
    # ATTITUDE every 0.1 s from t=0 to t=2.0 inclusive, heartbeat every 1 s.
    assert len(gcs.of_type("ATTITUDE")) == 21
    assert len(gcs.of_type("HEARTBEAT")) == 3
    hb = gcs.of_type("HEARTBEAT")[0]
    assert (hb.type, hb.autopilot) == (M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4)
    assert hb.custom_mode == 4 << 16 | 3 << 24  # AUTO.LOITER (Hold): PX4 SIH boots in it
    pos = gcs.of_type("GLOBAL_POSITION_INT")[-1]
    assert pos.lat == round(DEFAULT_HOME.lat_deg * 1e7)
    assert pos.relative_alt == 0


def test_ardupilot_sends_only_heartbeat_until_streams_are_requested(make_gcs):
    gcs = make_gcs(flavour=ARDUPILOT)
    gcs.run_until(3.0)
    assert {m.get_type() for m in gcs.received} == {"HEARTBEAT"}
    assert gcs.of_type("HEARTBEAT")[0].autopilot == M.MAV_AUTOPILOT_ARDUPILOTMEGA
    ack = gcs.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, 33, 200_000)
    assert ack.result == M.MAV_RESULT_ACCEPTED
    gcs.clear()
    gcs.run_until(4.0)
    assert len(gcs.of_type("GLOBAL_POSITION_INT")) in (5, 6)  # 5 Hz
    assert not gcs.of_type("ATTITUDE")
    # REQUEST_DATA_STREAM EXTRA1 (10) at 4 Hz switches ATTITUDE on.
    gcs.send(M.MAVLink_request_data_stream_message(1, 1, 10, 4, 1))
    gcs.clear()
    gcs.run_until(5.0)
    assert len(gcs.of_type("ATTITUDE")) in (4, 5)
    # ...and off again.
    gcs.send(M.MAVLink_request_data_stream_message(1, 1, 10, 0, 0))
    gcs.clear()
    gcs.run_until(6.0)
    assert not gcs.of_type("ATTITUDE")


def test_set_message_interval_minus_one_stops_and_zero_restores_default(make_gcs):
    gcs = make_gcs(flavour=PX4)
    gcs.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, 30, -1)
    gcs.clear()
    gcs.run_until(1.0)
    assert not gcs.of_type("ATTITUDE")
    gcs.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, 30, 0)
    gcs.clear()
    gcs.run_until(2.0)
    assert len(gcs.of_type("ATTITUDE")) in (10, 11)
    # a message PX4 lacks, and HEARTBEAT: FAILED, as PX4 SIH answers (docs/sitl.md)
    assert gcs.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, 9999, 1000).result == (
        M.MAV_RESULT_FAILED)
    assert gcs.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, 193, 1000).result == (
        M.MAV_RESULT_FAILED)  # EKF_STATUS_REPORT, ArduPilot's
    assert gcs.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, 0, 500_000).result == (
        M.MAV_RESULT_FAILED)
    assert gcs.command(M.MAV_CMD_REQUEST_MESSAGE, 193).result == M.MAV_RESULT_DENIED
    gcs.clear()
    assert gcs.command(M.MAV_CMD_GET_MESSAGE_INTERVAL, 193).result == M.MAV_RESULT_ACCEPTED
    assert [(i.message_id, i.interval_us) for i in gcs.of_type("MESSAGE_INTERVAL")] == [(193, 0)]


def test_ardupilot_denies_an_interval_for_a_message_it_lacks(make_gcs):
    """As ArduCopter 4.5 SITL answers (measured): DENIED and "No ap_message for mavlink id
    (N)" for ESTIMATOR_STATUS (230, PX4's); PX4 SIH answers FAILED (test above)."""
    gcs = make_gcs(flavour=ARDUPILOT)
    assert gcs.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, 230, 1_000_000).result == (
        M.MAV_RESULT_DENIED)
    assert "No ap_message for mavlink id (230)" in [t.text for t in gcs.of_type("STATUSTEXT")]
    assert gcs.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, 193, 1_000_000).result == (
        M.MAV_RESULT_ACCEPTED)  # EKF_STATUS_REPORT


def test_streams_go_no_faster_than_the_autopilot_loop(make_gcs):
    """ArduPilot's cap_message_interval (0.8 x 400 Hz: 3 ms): a faster SET_MESSAGE_INTERVAL
    is TEMPORARILY_REJECTED, under 1 ms it is 0 ms, which stops the stream; REQUEST_DATA_STREAM
    at its uint16 maximum is capped. PX4 is capped at 1 ms. (A 65535 Hz request used to make
    the vehicle build 65535 messages per simulated second.)"""
    gcs = make_gcs(flavour=ARDUPILOT)
    assert gcs.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, 30, 2_000).result == (
        M.MAV_RESULT_TEMPORARILY_REJECTED)
    assert gcs.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, 30, 3_000).result == M.MAV_RESULT_ACCEPTED
    gcs.clear()
    gcs.run_until(1.0)
    assert 300 <= len(gcs.of_type("ATTITUDE")) <= 335
    assert gcs.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, 30, 500).result == M.MAV_RESULT_ACCEPTED
    gcs.clear()
    gcs.run_until(2.0)
    assert not gcs.of_type("ATTITUDE")
    gcs.send(M.MAVLink_request_data_stream_message(1, 1, 10, 65535, 1))
    gcs.clear()
    gcs.run_until(3.0)
    assert 300 <= len(gcs.of_type("ATTITUDE")) <= 335

    px4 = make_gcs(flavour=PX4)
    assert px4.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, 30, 1).result == M.MAV_RESULT_ACCEPTED
    px4.clear()
    px4.run_until(1.0)
    assert 990 <= len(px4.of_type("ATTITUDE")) <= 1002


def test_request_message_sends_autopilot_version_after_the_ack(make_gcs):
    gcs = make_gcs(flavour=PX4)
    gcs.clear()
    ack = gcs.command(M.MAV_CMD_REQUEST_MESSAGE, 148)
    assert ack.result == M.MAV_RESULT_ACCEPTED
    version = gcs.of_type("AUTOPILOT_VERSION")
    assert len(version) == 1
    assert version[0].capabilities & M.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    assert version[0].capabilities & M.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
    assert gcs.received.index(ack) < gcs.received.index(version[0])


@pytest.mark.parametrize("mode_number", [6, 9])  # RTL, LAND
def test_ardupilot_refuses_to_arm_in_rtl_and_land(make_gcs, mode_number):
    gcs = make_gcs(flavour=ARDUPILOT)
    ack = gcs.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mode_number)
    assert ack.result == M.MAV_RESULT_ACCEPTED
    gcs.clear()
    ack = gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert ack.result == M.MAV_RESULT_FAILED
    assert any("not armable" in m.text for m in gcs.of_type("STATUSTEXT"))
    assert not gcs.core.fc.state.armed
    gcs.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 5)  # LOITER
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
    gcs.run_until(1.1)
    assert gcs.of_type("HEARTBEAT")[-1].base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED


def test_ardupilot_takeoff_needs_guided(make_gcs):
    gcs = make_gcs(flavour=ARDUPILOT)
    gcs.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 5)
    gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert gcs.command(M.MAV_CMD_NAV_TAKEOFF, *[0.0] * 6, 12.0).result == M.MAV_RESULT_FAILED
    gcs.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4)
    assert gcs.command(M.MAV_CMD_NAV_TAKEOFF, *[0.0] * 6, 12.0).result == (
        M.MAV_RESULT_ACCEPTED)
    gcs.run_until(20.0)
    assert gcs.core.fc.state.alt_m == pytest.approx(12.0, abs=0.3)
    assert gcs.core.fc.mode is Mode.GUIDED


def test_px4_integer_params_are_byte_encoded_and_floats_are_not(make_gcs):
    gcs = make_gcs(flavour=PX4)
    gcs.send(M.MAVLink_param_request_read_message(1, 1, b"SYS_AUTOSTART", -1))
    value = gcs.of_type("PARAM_VALUE")[-1]
    assert value.param_type == M.MAV_PARAM_TYPE_INT32
    assert struct.unpack("<i", struct.pack("<f", value.param_value))[0] == 4001
    gcs.send(M.MAVLink_param_request_read_message(1, 1, b"MIS_TAKEOFF_ALT", -1))
    value = gcs.of_type("PARAM_VALUE")[-1]
    assert (value.param_type, value.param_value) == (M.MAV_PARAM_TYPE_REAL32, 2.5)
    # PARAM_SET of an int, byte-encoded the PX4 way, is echoed and takes effect.
    raw = struct.unpack("<f", struct.pack("<i", 4))[0]
    gcs.send(M.MAVLink_param_set_message(1, 1, b"COM_RC_IN_MODE", raw,
                                         M.MAV_PARAM_TYPE_INT32))
    echo = gcs.of_type("PARAM_VALUE")[-1]
    assert echo.param_id == "COM_RC_IN_MODE"
    assert struct.unpack("<i", struct.pack("<f", echo.param_value))[0] == 4
    assert gcs.core.params.get("COM_RC_IN_MODE") == 4.0


def test_ardupilot_integer_params_are_c_cast(make_gcs):
    gcs = make_gcs(flavour=ARDUPILOT, system_id=7)
    gcs.send(M.MAVLink_param_request_read_message(7, 1, b"SYSID_THISMAV", -1))
    value = gcs.of_type("PARAM_VALUE")[-1]
    assert (value.param_type, value.param_value) == (M.MAV_PARAM_TYPE_INT16, 7.0)


def test_param_list_sends_every_param_with_its_index(make_gcs):
    gcs = make_gcs(flavour=PX4)
    gcs.send(M.MAVLink_param_request_list_message(1, 1))
    values = gcs.of_type("PARAM_VALUE")
    count = len(gcs.core.params)
    assert [v.param_index for v in values] == list(range(count))
    assert {v.param_count for v in values} == {count}
    # Unknown names are ignored and counted, never answered with garbage.
    gcs.send(M.MAVLink_param_set_message(1, 1, b"NO_SUCH_PARAM", 1.0, 9))
    assert gcs.core.counters["unknown_param"] == 1


def test_takeoff_altitude_param_and_px4_amsl_param7(make_gcs):
    gcs = make_gcs(flavour=PX4, params={"MIS_TAKEOFF_ALT": 10.0})
    gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert gcs.command(M.MAV_CMD_NAV_TAKEOFF, *[0.0] * 6, math.nan).result == 0
    gcs.run_until(15.0)
    assert gcs.core.fc.state.alt_m == pytest.approx(10.0, abs=0.3)
    assert gcs.core.fc.mode is Mode.HOLD  # PX4 holds after AUTO.TAKEOFF
    gcs2 = make_gcs(flavour=PX4)
    gcs2.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    gcs2.command(M.MAV_CMD_NAV_TAKEOFF, *[0.0] * 6, DEFAULT_HOME.alt_m + 15.0)
    gcs2.run_until(15.0)
    assert gcs2.core.fc.state.alt_m == pytest.approx(15.0, abs=0.3)


def _item(seq, command, lat=0.0, lon=0.0, z=0.0, frame=6, p1=0.0, p2=0.0):
    return M.MAVLink_mission_item_int_message(
        1, 1, seq, frame, command, 0, 1, p1, p2, 0.0, 0.0, round(lat * 1e7), round(lon * 1e7),
        z, 0)


def _upload(gcs, items):
    gcs.send(M.MAVLink_mission_count_message(1, 1, len(items), 0))
    for _ in items:
        req = gcs.of_type("MISSION_REQUEST_INT")[-1]
        gcs.send(items[req.seq])
    ack = gcs.of_type("MISSION_ACK")[-1]
    assert ack.type == M.MAV_MISSION_ACCEPTED
    return ack


def _square_mission(home_item=False):
    lat, lon = DEFAULT_HOME.lat_deg, DEFAULT_HOME.lon_deg
    d = 30.0 / 111_200.0  # ~30 m north
    items = [
        _item(0, M.MAV_CMD_NAV_TAKEOFF, z=10.0),
        _item(1, M.MAV_CMD_NAV_WAYPOINT, lat + d, lon, 10.0),
        _item(2, M.MAV_CMD_NAV_WAYPOINT, lat + d, lon + 1.5 * d, 10.0),
        _item(3, M.MAV_CMD_NAV_LAND, lat, lon + 1.5 * d, 0.0),
    ]
    if home_item:
        items = [_item(0, M.MAV_CMD_NAV_WAYPOINT, lat, lon, DEFAULT_HOME.alt_m, frame=0)] + [
            _item(i + 1, m.command, m.x / 1e7, m.y / 1e7, m.z) for i, m in enumerate(items)]
    return items


@pytest.mark.parametrize("flavour", [PX4, ARDUPILOT], ids=["px4", "ardupilot"])
def test_mission_upload_download_and_auto_flight(make_gcs, flavour):
    gcs = make_gcs(flavour=flavour)
    ap = flavour is ARDUPILOT
    items = _square_mission(home_item=ap)
    _upload(gcs, items)
    # Download: the same items back (ArduPilot reports home as item 0).
    gcs.send(M.MAVLink_mission_request_list_message(1, 1, 0))
    assert gcs.of_type("MISSION_COUNT")[-1].count == len(items)
    for seq, sent in enumerate(items):
        gcs.send(M.MAVLink_mission_request_int_message(1, 1, seq, 0))
        got = gcs.of_type("MISSION_ITEM_INT")[-1]
        assert (got.seq, got.command, got.x, got.y) == (seq, sent.command, sent.x, sent.y)
    gcs.send(M.MAVLink_mission_ack_message(1, 1, 0, 0))
    # Fly it: PX4 via MISSION_START, ArduPilot by switching to AUTO.
    if ap:
        gcs.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 5)
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
    if ap:
        assert gcs.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                           3).result == 0
    else:
        assert gcs.command(M.MAV_CMD_MISSION_START, 0, 0).result == 0
    gcs.run_until(120.0, stop=lambda: not gcs.core.fc.state.armed)
    first = 1 if ap else 0
    reached = [m.seq for m in gcs.of_type("MISSION_ITEM_REACHED")]
    assert reached == list(range(first, len(items)))
    st = gcs.core.fc.state
    assert st.on_ground and not st.armed  # landed at the end and disarmed itself
    east = st.position_ned_m[1]
    assert east == pytest.approx(1.5 * 30.0 * math.cos(math.radians(DEFAULT_HOME.lat_deg))
                                 * 111_320 / 111_200, abs=1.5)
    assert gcs.of_type("MISSION_CURRENT")[-1].seq == len(items) - 1


def test_mission_upload_rerequests_a_lost_item_at_the_timeout(make_gcs):
    gcs = make_gcs(flavour=PX4, protocol_timeout_s=1.0)
    gcs.now = 5.0
    gcs.send(M.MAVLink_mission_count_message(1, 1, 2, 0))
    assert gcs.of_type("MISSION_REQUEST_INT")[-1].seq == 0
    assert gcs.core._upload is not None and gcs.core._upload.deadline == 6.0
    gcs.clear()
    gcs.run_until(6.0)  # the item was "lost": the request comes again at exactly t=6
    assert [m.seq for m in gcs.of_type("MISSION_REQUEST_INT")] == [0]
    items = _square_mission()[:2]
    gcs.send(M.MAVLink_mission_count_message(1, 1, 2, 0))
    gcs.send(items[0])
    gcs.send(items[0])  # duplicate: re-request item 1, don't store twice
    assert gcs.core.counters["mission_item_out_of_sequence"] == 1
    gcs.send(items[1])
    assert gcs.of_type("MISSION_ACK")[-1].type == M.MAV_MISSION_ACCEPTED
    assert len(gcs.core.fc.mission) == 2


def test_mission_clear_and_set_current(make_gcs):
    gcs = make_gcs(flavour=PX4)
    _upload(gcs, _square_mission())
    gcs.send(M.MAVLink_mission_set_current_message(1, 1, 2))
    assert gcs.of_type("MISSION_CURRENT")[-1].seq == 2
    gcs.send(M.MAVLink_mission_clear_all_message(1, 1, 0))
    assert gcs.of_type("MISSION_ACK")[-1].type == M.MAV_MISSION_ACCEPTED
    gcs.send(M.MAVLink_mission_request_list_message(1, 1, 0))
    assert gcs.of_type("MISSION_COUNT")[-1].count == 0
    assert gcs.command(M.MAV_CMD_MISSION_START, 0, 0).result == M.MAV_RESULT_DENIED


def test_px4_offboard_velocity_setpoints_and_failsafe(make_gcs):
    gcs = make_gcs(flavour=PX4, params={"MIS_TAKEOFF_ALT": 5.0})
    gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    gcs.command(M.MAV_CMD_NAV_TAKEOFF, *[0.0] * 6, math.nan)
    gcs.run_until(10.0)
    # Offboard is refused without a recent setpoint stream.
    assert gcs.command(M.MAV_CMD_DO_SET_MODE, *_px4_mode_params(6)).result == M.MAV_RESULT_DENIED
    mask = 0b0000_1101_1100_0111  # velocity only, no yaw
    def setpoint():
        gcs.send(M.MAVLink_set_position_target_local_ned_message(
            int(gcs.now * 1000), 1, 1, M.MAV_FRAME_LOCAL_NED, mask, 0, 0, 0, 2.0, 0.0, 0.0,
            0, 0, 0, 0, 0))
    setpoint()
    assert gcs.command(M.MAV_CMD_DO_SET_MODE, *_px4_mode_params(6)).result == 0
    north0 = gcs.core.fc.state.position_ned_m[0]
    for k in range(1, 51):  # 5 s of setpoints at 10 Hz
        gcs.run_until(10.0 + 0.1 * k)
        setpoint()
    moved = gcs.core.fc.state.position_ned_m[0] - north0
    assert 8.0 < moved < 10.0  # ~2 m/s for 5 s minus the acceleration phase
    assert gcs.core.fc.state.velocity_ned_m_s[0] == pytest.approx(2.0, abs=0.05)
    gcs.run_until(17.0)  # stream stopped: COM_OF_LOSS_T = 1 s later PX4 holds
    assert gcs.core.fc.mode is Mode.HOLD
    assert any("offboard" in m.text for m in gcs.of_type("STATUSTEXT"))


def test_timesync_echoes_ts1_and_stamps_tc1_with_vehicle_time(make_gcs):
    gcs = make_gcs(flavour=PX4)
    gcs.now = 12.5
    gcs.send(M.MAVLink_timesync_message(0, 123456789))
    reply = gcs.of_type("TIMESYNC")[-1]
    assert (reply.tc1, reply.ts1) == (12_500_000_000, 123456789)


def test_bad_bytes_are_counted_and_the_vehicle_keeps_answering(make_gcs):
    gcs = make_gcs(flavour=PX4)
    gcs.core.receive_datagram(b"\xfd\x09garbage-not-mavlink" * 3, ("x", 1), 0.0)
    frame = bytearray(M.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3).pack(
        M.MAVLink(None, 255, 190)))
    frame[-1] ^= 0xFF  # break the CRC
    gcs.core.receive_datagram(bytes(frame), ("x", 1), 0.0)
    assert gcs.core.counters["bad_data"] + gcs.core.counters["malformed"] >= 2
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
    assert gcs.command(31337).result == M.MAV_RESULT_UNSUPPORTED


def test_commands_for_another_system_are_ignored(make_gcs):
    gcs = make_gcs(flavour=PX4, system_id=3)
    gcs.send(M.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0))
    assert not gcs.of_type("COMMAND_ACK")
    assert gcs.core.counters["not_for_us"] == 1
    assert not gcs.core.fc.state.armed


def test_battery_drains_in_flight_and_rtl_lands_at_home(make_gcs):
    gcs = make_gcs(flavour=PX4, params={"MIS_TAKEOFF_ALT": 10.0, "RTL_RETURN_ALT": 15.0})
    gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    gcs.command(M.MAV_CMD_NAV_TAKEOFF, *[0.0] * 6, math.nan)
    gcs.run_until(10.0)
    lat, lon = DEFAULT_HOME.lat_deg + 40 / 111_200, DEFAULT_HOME.lon_deg
    assert gcs.command(M.MAV_CMD_DO_REPOSITION, -1, 0, 0, math.nan, lat, lon,
                       DEFAULT_HOME.alt_m + 10).result == 0
    gcs.run_until(30.0)
    assert gcs.core.fc.state.position_ned_m[0] == pytest.approx(40.0, abs=1.0)
    level_before = gcs.core.fc.state.battery_remaining
    gcs.command(M.MAV_CMD_NAV_RETURN_TO_LAUNCH)
    gcs.run_until(120.0, stop=lambda: not gcs.core.fc.state.armed)
    st = gcs.core.fc.state
    assert st.on_ground and not st.armed
    assert math.hypot(st.position_ned_m[0], st.position_ned_m[1]) < 1.0
    assert st.battery_remaining < level_before < 1.0
    battery = gcs.of_type("BATTERY_STATUS")[-1]
    assert battery.battery_remaining == round(st.battery_remaining * 100)
    landed = [m.landed_state for m in gcs.of_type("EXTENDED_SYS_STATE")]
    assert M.MAV_LANDED_STATE_IN_AIR in landed and M.MAV_LANDED_STATE_LANDING in landed
    assert landed[-1] == M.MAV_LANDED_STATE_ON_GROUND


def test_ping_requests_are_answered_to_the_sender(make_gcs):
    gcs = make_gcs(flavour=PX4)
    gcs.send(M.MAVLink_ping_message(123, 7, 0, 0))
    reply = gcs.of_type("PING")[-1]
    assert (reply.time_usec, reply.seq, reply.target_system, reply.target_component) == (
        123, 7, 255, 190)
    gcs.send(M.MAVLink_ping_message(123, 8, 1, 1))  # a reply to us: not answered again
    assert len(gcs.of_type("PING")) == 1


def test_invalid_values_are_rejected_counted_and_explained(make_gcs):
    gcs = make_gcs(flavour=PX4)
    gcs.send(M.MAVLink_command_long_message(1, 1, M.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                            math.nan, 1000, 0, 0, 0, 0, 0))
    assert gcs.core.counters["invalid_command_long"] == 1
    assert "message_id" in gcs.of_type("STATUSTEXT")[-1].text
    # A mission item at latitude 123 is refused with the code naming param 5 (x).
    gcs.send(M.MAVLink_mission_count_message(1, 1, 1, 0))
    gcs.send(_item(0, M.MAV_CMD_NAV_WAYPOINT, 123.0, 8.5, 10.0))
    assert gcs.of_type("MISSION_ACK")[-1].type == M.MAV_MISSION_INVALID_PARAM5_X
    assert gcs.core.fc.mission == []
    # A NaN position target is dropped before it reaches the physics.
    gcs.send(M.MAVLink_set_position_target_local_ned_message(
        0, 1, 1, M.MAV_FRAME_LOCAL_NED, 0b0000_1111_1111_1000, math.nan, 0, 0, 0, 0, 0, 0, 0,
        0, 0, 0))
    assert gcs.core.counters["invalid_set_position_target_local_ned"] == 1


def test_a_terrain_frame_reposition_is_above_home_not_amsl(make_gcs):
    """COMMAND_INT DO_REPOSITION in MAV_FRAME_GLOBAL_TERRAIN_ALT_INT (11) at 20 m: the flat
    simulated ground makes terrain altitude the height above home."""
    gcs = make_gcs(flavour=PX4, params={"MIS_TAKEOFF_ALT": 10.0})
    gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    gcs.command(M.MAV_CMD_NAV_TAKEOFF, *[0.0] * 6, math.nan)
    gcs.run_until(10.0)
    lat, lon = DEFAULT_HOME.lat_deg + 20 / 111_200, DEFAULT_HOME.lon_deg
    gcs.send(M.MAVLink_command_int_message(1, 1, 11, M.MAV_CMD_DO_REPOSITION, 0, 0, -1, 0, 0,
                                           math.nan, int(lat * 1e7), int(lon * 1e7), 20.0))
    gcs.run_until(30.0)
    assert -gcs.core.fc.state.position_ned_m[2] == pytest.approx(20.0, abs=1.0)
