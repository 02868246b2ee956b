"""MAVLink messages as telemetry samples: the pure converter and the enum values it needs.

No socket and no thread here: :class:`MavlinkConverter` turns pymavlink message objects into
frozen samples in SI units, so it is tested without a link. PX4 sends integer parameters
byte-encoded in the float of PARAM_VALUE; ArduPilot sends their numeric value;
:func:`decode_param_value` decodes both.
"""


from __future__ import annotations

import math
import struct
from collections.abc import Callable
from typing import Any

from companion.telemetry import (
    AttitudeSample,
    BatterySample,
    CommandAckSample,
    EstimatorSample,
    GpsSample,
    HeartbeatSample,
    ParamSample,
    PositionSample,
    Sample,
    StatusTextSample,
    SystemTimeSample,
)

# MAVLink enum values used below (common.xml), spelled out so this module can be read
# and its converter tested without pymavlink's process-wide dialect.
MAV_AUTOPILOT_GENERIC = 0
MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_AUTOPILOT_INVALID = 8
MAV_AUTOPILOT_PX4 = 12
MAV_TYPE_ONBOARD_CONTROLLER = 18
MAV_TYPE_GCS = 6
NOT_A_VEHICLE = frozenset({MAV_TYPE_GCS, MAV_TYPE_ONBOARD_CONTROLLER, 26, 27, 30, 31, 32, 33, 34,
                           36, 37, 38, 39, 40, 41, 42})
"""MAV_TYPE of components that are never the autopilot: GCS, onboard controller, gimbal,
ADS-B, camera, charging station, FLARM, servo, OpenDroneID, battery, parachute, log, OSD,
IMU, GPS, winch."""
MAV_STATE_ACTIVE = 4
MAV_MODE_FLAG_SAFETY_ARMED = 128
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_CMD_DO_SET_MODE = 176
MAV_CMD_COMPONENT_ARM_DISARM = 400
MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_RESULT_ACCEPTED = 0
MAV_DATA_STREAM_ALL = 0
ESTIMATOR_POS_HORIZ_ABS = 16
"""ESTIMATOR_STATUS_FLAGS: the estimator has an absolute horizontal position (an origin)."""
ESTIMATOR_NOT_TRUSTED = 1024 | 32768
"""ESTIMATOR_GPS_GLITCH, ESTIMATOR_UNINITIALIZED."""
ESTIMATOR_CONST_POS_MODE = 128
"""Constant-position mode: trusted only while an absolute position source is fused (below)."""
ESTIMATOR_PRED_POS_HORIZ_ABS = 512
"""The estimator fuses an absolute horizontal position source (GNSS)."""
MAV_COMP_ID_ONBOARD_COMPUTER = 191
MAV_PARAM_TYPE_SIGNED = {2, 4, 6}  # INT8, INT16, INT32
MAV_PARAM_TYPE_UNSIGNED = {1, 3, 5}  # UINT8, UINT16, UINT32

AUTOPILOT_NAMES = {
    MAV_AUTOPILOT_GENERIC: "generic",
    MAV_AUTOPILOT_ARDUPILOTMEGA: "ardupilot",
    MAV_AUTOPILOT_PX4: "px4",
}




def decode_param_value(value: float, param_type: int, *, autopilot: str | None,
                       raw: bytes | None = None) -> int | float:
    """PARAM_VALUE's float as the parameter's real value.

    PX4 copies the bytes of an integer parameter into the float field (a float that often
    reads as a denormal); ArduPilot converts the integer to a float. Real parameters pass as
    is. ``raw`` (the 4 bytes of the field on the wire) is preferred for PX4: some integers are
    signalling-NaN bit patterns, which a float32 -> float64 -> float32 round trip alters.
    """
    if param_type in MAV_PARAM_TYPE_SIGNED or param_type in MAV_PARAM_TYPE_UNSIGNED:
        if autopilot == "px4":
            fmt = "<i" if param_type in MAV_PARAM_TYPE_SIGNED else "<I"
            bits = raw if raw is not None and len(raw) == 4 else struct.pack("<f", value)
            return int(struct.unpack(fmt, bits)[0])
        if math.isfinite(value):
            return round(value)
    return float(value)


def _none_if(value: float, sentinel: float) -> float | None:
    return None if value == sentinel else value


class MavlinkConverter:
    """Pure conversion of pymavlink message objects into telemetry samples (SI units).

    It keeps only what the conversion needs: which system and component is the autopilot
    (the first HEARTBEAT whose ``autopilot`` is not MAV_AUTOPILOT_INVALID, from a vehicle
    type) and its family, for mode
    names and PX4's parameter encoding. Messages from other systems are ignored.
    """

    def __init__(self) -> None:
        self.target_system: int | None = None
        self.target_component: int | None = None
        self.autopilot: str | None = None
        self.vehicle_type: int | None = None

    def convert(self, msg: Any, *, now: float) -> Sample | None:
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            return self._heartbeat(msg, now)
        # Only the autopilot's own component: the autopilot routes the other components of
        # its system (a camera, a gimbal, a payload app) to this link too.
        if self.target_system is None or (msg.get_srcSystem(), msg.get_srcComponent()) != (
                self.target_system, self.target_component):
            return None
        handler = _HANDLERS.get(kind)
        if handler is None:
            return None
        return handler(self, msg, now)

    def _heartbeat(self, msg: Any, now: float) -> HeartbeatSample | None:
        if msg.autopilot == MAV_AUTOPILOT_INVALID or msg.type in NOT_A_VEHICLE:
            return None
        system = msg.get_srcSystem()
        if self.target_system is None:
            self.target_system = system
            self.target_component = msg.get_srcComponent()
        elif (system, msg.get_srcComponent()) != (self.target_system, self.target_component):
            return None  # another system, or another component of the autopilot's system
        self.autopilot = AUTOPILOT_NAMES.get(msg.autopilot, f"autopilot{msg.autopilot}")
        self.vehicle_type = msg.type
        return HeartbeatSample(
            t=now,
            system_id=system,
            autopilot=self.autopilot,
            vehicle_type=msg.type,
            mode=_mode_name(msg),
            custom_mode=msg.custom_mode,
            base_mode=msg.base_mode,
            armed=bool(msg.base_mode & MAV_MODE_FLAG_SAFETY_ARMED),
            system_status=msg.system_status,
        )

    def _sys_status(self, msg: Any, now: float) -> BatterySample:
        voltage = _none_if(msg.voltage_battery, 65535)
        current = _none_if(msg.current_battery, -1)
        remaining = _none_if(msg.battery_remaining, -1)
        return BatterySample(
            t=now,
            source="SYS_STATUS",
            battery_v=None if voltage is None else voltage / 1000.0,
            current_a=None if current is None else current / 100.0,
            battery_remaining=None if remaining is None else remaining / 100.0,
        )

    def _battery_status(self, msg: Any, now: float) -> BatterySample:
        cells = [v for v in msg.voltages if v not in (65535, 0)]
        current = _none_if(msg.current_battery, -1)
        remaining = _none_if(msg.battery_remaining, -1)
        return BatterySample(
            t=now,
            source="BATTERY_STATUS",
            battery_v=sum(cells) / 1000.0 if cells else None,
            current_a=None if current is None else current / 100.0,
            battery_remaining=None if remaining is None else remaining / 100.0,
        )

    def _position(self, msg: Any, now: float) -> PositionSample:
        heading = _none_if(msg.hdg, 65535)
        return PositionSample(
            t=now,
            lat_deg=msg.lat * 1e-7,
            lon_deg=msg.lon * 1e-7,
            alt_amsl_m=msg.alt * 1e-3,
            alt_rel_m=msg.relative_alt * 1e-3,
            vn_m_s=msg.vx * 1e-2,
            ve_m_s=msg.vy * 1e-2,
            vd_m_s=msg.vz * 1e-2,
            heading_deg=None if heading is None else heading / 100.0,
        )

    def _attitude(self, msg: Any, now: float) -> AttitudeSample:
        return AttitudeSample(
            t=now, roll_rad=msg.roll, pitch_rad=msg.pitch, yaw_rad=msg.yaw,
            rollspeed_rad_s=msg.rollspeed, pitchspeed_rad_s=msg.pitchspeed,
            yawspeed_rad_s=msg.yawspeed,
        )

    def _gps(self, msg: Any, now: float) -> GpsSample:
        eph = _none_if(msg.eph, 65535)
        return GpsSample(
            t=now, fix_type=msg.fix_type, satellites=_int_or_none(msg.satellites_visible, 255),
            lat_deg=msg.lat * 1e-7, lon_deg=msg.lon * 1e-7, alt_m=msg.alt * 1e-3,
            eph_m=None if eph is None else eph / 100.0,
        )

    def _estimator(self, msg: Any, now: float) -> EstimatorSample:
        return EstimatorSample(t=now, source=msg.get_type(), flags=int(msg.flags),
                               position_ok=estimator_position_ok(int(msg.flags)))

    def _system_time(self, msg: Any, now: float) -> SystemTimeSample:
        return SystemTimeSample(
            t=now,
            unix_time_s=msg.time_unix_usec / 1e6 if msg.time_unix_usec else None,
            time_boot_s=msg.time_boot_ms / 1e3,
        )

    def _statustext(self, msg: Any, now: float) -> StatusTextSample:
        text = msg.text
        if isinstance(text, bytes):
            text = text.decode("utf-8", "replace")
        return StatusTextSample(t=now, severity=msg.severity, text=text.rstrip("\x00"))

    def _param(self, msg: Any, now: float) -> ParamSample:
        name = msg.param_id
        if isinstance(name, bytes):
            name = name.decode("ascii", "replace")
        return ParamSample(
            t=now, name=name.rstrip("\x00"),
            value=decode_param_value(msg.param_value, msg.param_type, autopilot=self.autopilot,
                                     raw=_param_value_bytes(msg)),
            index=msg.param_index, count=msg.param_count,
        )

    def _ack(self, msg: Any, now: float) -> CommandAckSample:
        return CommandAckSample(t=now, command=msg.command, result=msg.result,
                                target_system=int(getattr(msg, "target_system", 0) or 0),
                                target_component=int(getattr(msg, "target_component", 0) or 0))


def estimator_position_ok(flags: int) -> bool:
    """May the position be used, by ESTIMATOR_STATUS_FLAGS (EKF_STATUS_REPORT has the same)?

    An absolute horizontal position, no glitch, initialised. CONST_POS_MODE means two things:
    ArduPilot sets it while its EKF has no GPS yet (and then never POS_HORIZ_ABS); PX4 sets it
    whenever the vehicle is at rest (ekf2 ``get_ekf_soln_status``: ``vehicle_at_rest``), so a
    real PX4 SIH reports 1023 on the ground with GNSS fused. It disqualifies only when no
    absolute source is fused (PRED_POS_HORIZ_ABS clear: PX4's fake position on the ground).
    """
    if not flags & ESTIMATOR_POS_HORIZ_ABS or flags & ESTIMATOR_NOT_TRUSTED:
        return False
    return not flags & ESTIMATOR_CONST_POS_MODE or bool(flags & ESTIMATOR_PRED_POS_HORIZ_ABS)


def _param_value_bytes(msg: Any) -> bytes | None:
    """The 4 wire bytes of PARAM_VALUE.param_value (first payload field), if available."""
    get = getattr(msg, "get_msgbuf", None)
    buf = bytes(get()) if callable(get) else b""
    if not buf:
        return None
    header = 10 if buf[0] == 0xFD else 6  # MAVLink 2 or 1
    field = buf[header:header + 4]
    return field.ljust(4, b"\x00") if len(buf) > header else None  # v2 trims trailing zeros


def _int_or_none(value: int, sentinel: int) -> int | None:
    return None if value == sentinel else int(value)


PX4_MAIN_MODES = {1: "MANUAL", 2: "ALTCTL", 3: "POSCTL", 4: "AUTO", 5: "ACRO", 6: "OFFBOARD",
                  7: "STABILIZED", 8: "RATTITUDE", 9: "SIMPLE", 10: "TERMINATION",
                  11: "ALTITUDE_CRUISE"}
"""PX4's ``PX4_CUSTOM_MAIN_MODE`` (px4_custom_mode.h), in pymavlink's names where it has one."""
PX4_AUTO_SUB_MODES = {1: "READY", 2: "TAKEOFF", 3: "LOITER", 4: "MISSION", 5: "RTL", 6: "LAND",
                      7: "RTGS", 8: "FOLLOWME", 9: "PRECLAND", 10: "VTOL_TAKEOFF",
                      **{10 + i: f"EXTERNAL{i}" for i in range(1, 9)}}
"""``PX4_CUSTOM_SUB_MODE_AUTO``: pymavlink 2.4.50 names 1-8 but READY, PRECLAND, VTOL_TAKEOFF
and the external modes, so the dashboard showed "UNKNOWN" for a PX4 drone on the ground in
AUTO.READY or precision landing."""
PX4_POSCTL_SUB_MODES = {0: "POSCTL", 1: "ORBIT", 2: "POSCTL_SLOW"}


def px4_mode_name(custom_mode: int) -> str:
    """A PX4 HEARTBEAT's mode: main mode (bits 16-23) and, for AUTO and POSCTL, sub mode
    (bits 24-31); a number we do not know is shown as numbers, not as "UNKNOWN"."""
    main, sub = (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF
    table = {4: PX4_AUTO_SUB_MODES, 3: PX4_POSCTL_SUB_MODES}.get(main)
    if table is not None:
        return table.get(sub, f"{PX4_MAIN_MODES[main]}.{sub}")
    return PX4_MAIN_MODES.get(main, f"PX4 mode {main}.{sub}")


def _mode_name(msg: Any) -> str:
    from pymavlink import mavutil

    if getattr(msg, "autopilot", None) == mavutil.mavlink.MAV_AUTOPILOT_PX4:
        return px4_mode_name(int(msg.custom_mode))
    return str(mavutil.mode_string_v10(msg))


_HANDLERS: dict[str, Callable[[MavlinkConverter, Any, float], Sample]] = {
    "SYS_STATUS": MavlinkConverter._sys_status,
    "BATTERY_STATUS": MavlinkConverter._battery_status,
    "GLOBAL_POSITION_INT": MavlinkConverter._position,
    "ATTITUDE": MavlinkConverter._attitude,
    "GPS_RAW_INT": MavlinkConverter._gps,
    "SYSTEM_TIME": MavlinkConverter._system_time,
    "EKF_STATUS_REPORT": MavlinkConverter._estimator,
    "ESTIMATOR_STATUS": MavlinkConverter._estimator,
    "STATUSTEXT": MavlinkConverter._statustext,
    "PARAM_VALUE": MavlinkConverter._param,
    "COMMAND_ACK": MavlinkConverter._ack,
}


# ----------------------------------------------------------------------------- commands
