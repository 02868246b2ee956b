"""MAVLink messages become SI samples; samples build the telemetry snapshot."""

from __future__ import annotations

import math
import struct

from hypothesis import given
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mav
from pymavlink.generator.mavcrc import x25crc

from companion.mavlink import MavlinkConverter, decode_param_value
from companion.telemetry import (
    BatterySample,
    EstimatorSample,
    GpsSample,
    HeartbeatSample,
    LinkStateSample,
    ParamSample,
    PositionSample,
    TelemetryState,
)

T0 = 1_700_000_000.0


def _wire(msg: mav.MAVLink_message, *, system: int = 1, component: int = 1) -> object:
    """Pack and parse, so the converter sees what pymavlink hands the reader."""
    codec = mav.MAVLink(None, srcSystem=system, srcComponent=component)
    parsed = mav.MAVLink(None).parse_buffer(msg.pack(codec))
    assert parsed is not None and len(parsed) == 1
    return parsed[0]


def _heartbeat(autopilot: int = mav.MAV_AUTOPILOT_ARDUPILOTMEGA, custom_mode: int = 4,
               armed: bool = False, vtype: int = mav.MAV_TYPE_QUADROTOR) -> object:
    base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mav.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
    return _wire(mav.MAVLink_heartbeat_message(vtype, autopilot, base, custom_mode,
                                               mav.MAV_STATE_ACTIVE, 3))


def test_heartbeat_gives_mode_name_armed_and_autopilot() -> None:
    conv = MavlinkConverter()
    sample = conv.convert(_heartbeat(custom_mode=4, armed=True), now=T0)
    assert isinstance(sample, HeartbeatSample)
    assert (sample.mode, sample.armed, sample.autopilot, sample.t) == ("GUIDED", True,
                                                                       "ardupilot", T0)
    assert conv.target_system == 1


def test_px4_modes_pymavlink_does_not_name_are_named() -> None:
    """PX4 SIH sits in AUTO.READY before a mission and PRECLAND lands on a target; pymavlink
    2.4.50 calls both "UNKNOWN", which the dashboard showed (real PX4 check, 2026-11-24)."""
    def mode(main: int, sub: int) -> str:
        sample = MavlinkConverter().convert(
            _heartbeat(autopilot=mav.MAV_AUTOPILOT_PX4, custom_mode=(sub << 24) | (main << 16)),
            now=T0)
        assert isinstance(sample, HeartbeatSample)
        return sample.mode

    assert [mode(4, sub) for sub in (1, 3, 4, 9, 10, 11)] == [
        "READY", "LOITER", "MISSION", "PRECLAND", "VTOL_TAKEOFF", "EXTERNAL1"]
    assert [mode(3, 0), mode(3, 1), mode(2, 0), mode(6, 0), mode(10, 0)] == [
        "POSCTL", "ORBIT", "ALTCTL", "OFFBOARD", "TERMINATION"]
    assert (mode(4, 99), mode(42, 7)) == ("AUTO.99", "PX4 mode 42.7")  # not "UNKNOWN"


def test_gcs_and_companion_heartbeats_do_not_pick_the_target() -> None:
    conv = MavlinkConverter()
    gcs = _wire(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID,
                                              0, 0, 0, 3), system=255)
    assert conv.convert(gcs, now=T0) is None
    assert conv.target_system is None
    pos = _wire(mav.MAVLink_global_position_int_message(0, 1, 1, 1, 1, 0, 0, 0, 0))
    assert conv.convert(pos, now=T0) is None  # no autopilot known yet


def test_position_in_si_units_and_unknown_heading_is_none() -> None:
    conv = MavlinkConverter()
    conv.convert(_heartbeat(), now=T0)
    raw = mav.MAVLink_global_position_int_message(1000, 500_615_000, 199_373_000, 250_000,
                                                  30_500, 120, -340, 50, 65535)
    sample = conv.convert(_wire(raw), now=T0 + 1)
    assert isinstance(sample, PositionSample)
    assert math.isclose(sample.lat_deg, 50.0615, abs_tol=1e-9)
    assert math.isclose(sample.lon_deg, 19.9373, abs_tol=1e-9)
    assert sample.alt_amsl_m == 250.0 and sample.alt_rel_m == 30.5
    assert (sample.vn_m_s, sample.ve_m_s, sample.vd_m_s) == (1.2, -3.4, 0.5)
    assert sample.heading_deg is None


def test_sys_status_battery_and_sentinels() -> None:
    conv = MavlinkConverter()
    conv.convert(_heartbeat(), now=T0)
    raw = mav.MAVLink_sys_status_message(0, 0, 0, 500, 12_345, -1, 42, 0, 0, 0, 0, 0, 0)
    sample = conv.convert(_wire(raw), now=T0)
    assert sample == BatterySample(t=T0, source="SYS_STATUS", battery_v=12.345, current_a=None,
                                   battery_remaining=0.42)
    raw = mav.MAVLink_sys_status_message(0, 0, 0, 500, 65535, 250, -1, 0, 0, 0, 0, 0, 0)
    sample = conv.convert(_wire(raw), now=T0)
    assert sample == BatterySample(t=T0, source="SYS_STATUS", battery_v=None, current_a=2.5,
                                   battery_remaining=None)


def test_battery_status_sums_known_cells() -> None:
    conv = MavlinkConverter()
    conv.convert(_heartbeat(), now=T0)
    cells = [4000, 4100, 4200] + [65535] * 7
    raw = mav.MAVLink_battery_status_message(0, 0, 0, 2500, cells, 1000, -1, -1, 80)
    sample = conv.convert(_wire(raw), now=T0)
    assert isinstance(sample, BatterySample)
    assert math.isclose(sample.battery_v or 0.0, 12.3) and sample.current_a == 10.0
    assert sample.battery_remaining == 0.8


def test_other_systems_are_ignored() -> None:
    conv = MavlinkConverter()
    conv.convert(_heartbeat(), now=T0)
    raw = mav.MAVLink_attitude_message(0, 0.1, 0.2, 0.3, 0, 0, 0)
    assert conv.convert(_wire(raw, system=2), now=T0) is None
    assert conv.convert(_wire(raw, system=1), now=T0) is not None


def test_other_components_of_the_autopilots_system_are_ignored() -> None:
    """The autopilot routes its system's other components to the companion's link: a MAVSDK
    camera or payload app (system 1, its own component; MAVSDK's server heartbeat says
    MAV_TYPE_GENERIC / MAV_AUTOPILOT_GENERIC, docs/sitl.md) must not become the autopilot:
    the dashboard's mode and armed state flipped to it at each of its HEARTBEATs."""
    conv = MavlinkConverter()
    camera = mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GENERIC, mav.MAV_AUTOPILOT_GENERIC, 0,
                                           0, mav.MAV_STATE_ACTIVE, 3)
    gimbal = mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GIMBAL, mav.MAV_AUTOPILOT_GENERIC, 0,
                                           0, mav.MAV_STATE_ACTIVE, 3)
    # heard before the autopilot: a gimbal is never taken for it
    assert conv.convert(_wire(gimbal, component=154), now=T0) is None
    sample = conv.convert(_heartbeat(armed=True), now=T0)
    assert isinstance(sample, HeartbeatSample) and sample.armed is True
    assert (conv.target_system, conv.target_component) == (1, 1)
    assert conv.convert(_wire(camera, component=100), now=T0) is None
    raw = mav.MAVLink_attitude_message(0, 0.1, 0.2, 0.3, 0, 0, 0)
    assert conv.convert(_wire(raw, component=100), now=T0) is None
    text = mav.MAVLink_statustext_message(mav.MAV_SEVERITY_INFO, b"camera ready")
    assert conv.convert(_wire(text, component=100), now=T0) is None
    assert conv.convert(_wire(raw), now=T0) is not None


def _px4_param_frame(name: bytes, value: int) -> object:
    """A PARAM_VALUE frame as PX4 writes it: the int32's bytes memcpy'd into the float field.

    Built by hand because a Python float cannot carry every float32 bit pattern (signalling
    NaNs get quieted), so pymavlink's own ``pack`` cannot produce it.
    """
    msg_id = mav.MAVLINK_MSG_ID_PARAM_VALUE
    payload = struct.pack("<iHH16sB", value, 10, 3, name, mav.MAV_PARAM_TYPE_INT32)
    header = struct.pack("<BBBBBBBHB", 0xFD, len(payload), 0, 0, 0, 1, 1, msg_id & 0xFFFF,
                         msg_id >> 16)
    crc = x25crc(header[1:] + payload)
    crc.accumulate(bytes([mav.MAVLink_param_value_message.crc_extra]))
    parsed = mav.MAVLink(None).parse_buffer(header + payload + struct.pack("<H", crc.crc))
    assert parsed is not None and len(parsed) == 1
    return parsed[0]


@given(st.integers(min_value=-(2**31), max_value=2**31 - 1))
def test_px4_int32_params_are_byte_decoded(value: int) -> None:
    """Through pymavlink's own parser, including NaN bit patterns (e.g. -4194305)."""
    conv = MavlinkConverter()
    conv.convert(_heartbeat(autopilot=mav.MAV_AUTOPILOT_PX4, custom_mode=0), now=T0)
    sample = conv.convert(_px4_param_frame(b"MAV_SYS_ID", value), now=T0)
    assert isinstance(sample, ParamSample) and sample.name == "MAV_SYS_ID"
    assert sample.value == value


@given(st.integers(min_value=0, max_value=2**24))
def test_ardupilot_int_params_are_numeric(value: int) -> None:
    assert decode_param_value(float(value), mav.MAV_PARAM_TYPE_INT32,
                              autopilot="ardupilot") == value


def test_real_params_pass_unchanged() -> None:
    assert decode_param_value(2.5, mav.MAV_PARAM_TYPE_REAL32, autopilot="px4") == 2.5


def test_state_snapshot_and_reconnect_count() -> None:
    state = TelemetryState()
    seen: list[object] = []
    state.add_listener(seen.append)
    assert state.snapshot().connected is False
    state.apply(LinkStateSample(t=T0, connected=True, reason="hb"))
    state.apply(GpsSample(t=T0, fix_type=3, satellites=9, lat_deg=1.0, lon_deg=2.0, alt_m=3.0,
                          eph_m=1.0))  # a position counts with a 3-D fix only
    state.apply(EstimatorSample(t=T0, source="EKF_STATUS_REPORT", flags=0,
                                position_ok=True))  # ... and the estimator's word on a new link
    state.apply(PositionSample(t=T0, lat_deg=1.0, lon_deg=2.0, alt_amsl_m=3.0, alt_rel_m=4.0,
                               vn_m_s=0, ve_m_s=0, vd_m_s=0, heading_deg=None))
    snap = state.snapshot()
    assert (snap.connected, snap.lat_deg, snap.alt_rel_m, snap.reconnects) == (True, 1.0, 4.0, 0)
    assert snap.geotag() == {"lat_deg": 1.0, "lon_deg": 2.0, "alt_rel_m": 4.0, "alt_amsl_m": 3.0}
    state.apply(LinkStateSample(t=T0 + 5, connected=False, reason="silence"))
    state.apply(LinkStateSample(t=T0 + 9, connected=True, reason="hb"))
    assert state.snapshot().reconnects == 1
    assert snap.connected is True  # snapshots are immutable copies
    assert len(seen) == 6  # every applied sample reached the listener


def test_battery_sample_keeps_previous_known_fields() -> None:
    state = TelemetryState()
    state.apply(BatterySample(t=T0, source="SYS_STATUS", battery_v=12.0, current_a=None,
                              battery_remaining=0.5))
    state.apply(BatterySample(t=T0 + 1, source="BATTERY_STATUS", battery_v=None,
                              current_a=3.0, battery_remaining=None))
    snap = state.snapshot()
    assert (snap.battery_v, snap.current_a, snap.battery_remaining) == (12.0, 3.0, 0.5)
