"""Telemetry messages of a simulated vehicle, built from the flight controller's state.

Pure: each builder takes the vehicle time ``now`` (simulated seconds since boot) and returns a
pymavlink message object; scheduling (which stream, how often) belongs to
:class:`~sitl.vehicle.core.VehicleCore`. Raw MAVLink scaling (degE7, mm, cm/s, cdeg, mV, cA)
happens here and nowhere else.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from sitl.geo import Enu, GeoPoint, geo_from_enu
from sitl.vehicle.autopilot import FlightController
from sitl.vehicle.flavour import Flavour, Mode
from sitl.vehicle.physics import gps_reading

__all__ = ["DEFAULT_INTERVALS_S", "MSG_HEARTBEAT", "STREAM_GROUPS", "Telemetry"]

MSG_HEARTBEAT = 0
MSG_SYS_STATUS = 1
MSG_SYSTEM_TIME = 2
MSG_GPS_RAW_INT = 24
MSG_ATTITUDE = 30
MSG_LOCAL_POSITION_NED = 32
MSG_GLOBAL_POSITION_INT = 33
MSG_MISSION_CURRENT = 42
MSG_VFR_HUD = 74
MSG_BATTERY_STATUS = 147
MSG_AUTOPILOT_VERSION = 148
MSG_HOME_POSITION = 242
MSG_EXTENDED_SYS_STATE = 245

# Default rates (interval in s) of a PX4 "normal" link; also what interval 0 restores.
DEFAULT_INTERVALS_S: Mapping[int, float] = {
    MSG_HEARTBEAT: 1.0,
    MSG_SYS_STATUS: 1.0,
    MSG_SYSTEM_TIME: 1.0,
    MSG_GPS_RAW_INT: 1.0,
    MSG_ATTITUDE: 0.1,
    MSG_LOCAL_POSITION_NED: 0.2,
    MSG_GLOBAL_POSITION_INT: 0.2,
    MSG_MISSION_CURRENT: 1.0,
    MSG_VFR_HUD: 0.25,
    MSG_BATTERY_STATUS: 2.0,
    MSG_HOME_POSITION: 2.0,
    MSG_EXTENDED_SYS_STATE: 1.0,
}

# ArduPilot REQUEST_DATA_STREAM groups (MAV_DATA_STREAM) -> the messages we have of each.
STREAM_GROUPS: Mapping[int, tuple[int, ...]] = {
    2: (MSG_SYS_STATUS, MSG_GPS_RAW_INT, MSG_MISSION_CURRENT, MSG_EXTENDED_SYS_STATE),
    6: (MSG_GLOBAL_POSITION_INT, MSG_LOCAL_POSITION_NED),
    10: (MSG_ATTITUDE,),
    11: (MSG_VFR_HUD,),
    12: (MSG_SYSTEM_TIME, MSG_BATTERY_STATUS),
}

_SENSORS = (1 | 2 | 4 | 8 | 32 | 1024 | 2048 | 4096 | 8192 | 16384 | 32768 | (1 << 21)
            | (1 << 25) | (1 << 28))
_CAPABILITIES = (
    mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_RALLY
)


class Telemetry:
    """Builds every telemetry message the vehicle streams or sends on request."""

    def __init__(self, fc: FlightController, *, flavour: Flavour, system_id: int,
                 home: GeoPoint, boot_unix_s: float, gps_sigma_h_m: float,
                 rng: np.random.Generator, mission_total: Callable[[], int]) -> None:
        self.fc = fc
        self.flavour = flavour
        self.system_id = system_id
        self.home = home
        self.boot_unix_s = boot_unix_s
        self.gps_sigma_h_m = gps_sigma_h_m
        self.rng = rng
        self.mission_total = mission_total
        self.builders: Mapping[int, Callable[[float], Any]] = {
            MSG_HEARTBEAT: self.heartbeat,
            MSG_SYS_STATUS: self.sys_status,
            MSG_SYSTEM_TIME: self.system_time,
            MSG_GPS_RAW_INT: self.gps_raw_int,
            MSG_ATTITUDE: self.attitude,
            MSG_LOCAL_POSITION_NED: self.local_position_ned,
            MSG_GLOBAL_POSITION_INT: self.global_position_int,
            MSG_MISSION_CURRENT: self.mission_current,
            MSG_VFR_HUD: self.vfr_hud,
            MSG_BATTERY_STATUS: self.battery_status,
            MSG_AUTOPILOT_VERSION: self.autopilot_version,
            MSG_HOME_POSITION: self.home_position,
            MSG_EXTENDED_SYS_STATE: self.extended_sys_state,
        }

    def ned_to_geo(self, ned: tuple[float, float, float]) -> GeoPoint:
        return geo_from_enu(Enu(east_m=ned[1], north_m=ned[0], up_m=-ned[2]), self.home)

    def boot_ms(self, now: float) -> int:
        return int(now * 1000) & 0xFFFFFFFF

    def heartbeat(self, now: float) -> Any:
        fc = self.fc
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
        if fc.mode in (Mode.MISSION, Mode.GUIDED, Mode.RTL, Mode.LAND, Mode.TAKEOFF,
                       Mode.HOLD):
            base |= mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
        if fc.mode is Mode.MISSION:
            base |= mavlink.MAV_MODE_FLAG_AUTO_ENABLED
        if fc.state.armed:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        status = mavlink.MAV_STATE_ACTIVE if fc.state.armed else mavlink.MAV_STATE_STANDBY
        if fc.state.battery_remaining < 0.07:
            status = mavlink.MAV_STATE_CRITICAL
        return mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_QUADROTOR, self.flavour.autopilot, base,
            self.flavour.custom_mode(fc.mode), status, 3)

    def sys_status(self, now: float) -> Any:
        st = self.fc.state
        return mavlink.MAVLink_sys_status_message(
            _SENSORS, _SENSORS, _SENSORS, 250, int(st.battery_voltage_v * 1000),
            int(st.battery_current_a * 100), round(st.battery_remaining * 100),
            0, 0, 0, 0, 0, 0)

    def system_time(self, now: float) -> Any:
        return mavlink.MAVLink_system_time_message(
            int((self.boot_unix_s + now) * 1e6), self.boot_ms(now))

    def gps_raw_int(self, now: float) -> Any:
        fix = gps_reading(self.fc.state, self.rng, sigma_h_m=self.gps_sigma_h_m)
        geo = self.ned_to_geo(fix.position_ned_m)
        vn, ve = fix.velocity_ned_m_s[0], fix.velocity_ned_m_s[1]
        cog = round(math.degrees(math.atan2(ve, vn)) % 360.0 * 100) % 36000
        return mavlink.MAVLink_gps_raw_int_message(
            int((self.boot_unix_s + now) * 1e6), 3, round(geo.lat_deg * 1e7),
            round(geo.lon_deg * 1e7), round(geo.alt_m * 1000), 80, 120,
            int(math.hypot(vn, ve) * 100), cog, fix.satellites, round(geo.alt_m * 1000),
            int(fix.eph_m * 1000), int(fix.epv_m * 1000), 100, 0, 0)

    def attitude(self, now: float) -> Any:
        st = self.fc.state
        return mavlink.MAVLink_attitude_message(
            self.boot_ms(now), st.roll_rad, st.pitch_rad, st.yaw_rad, 0.0, 0.0,
            st.yaw_rate_rad_s)

    def local_position_ned(self, now: float) -> Any:
        st = self.fc.state
        p, v = st.position_ned_m, st.velocity_ned_m_s
        return mavlink.MAVLink_local_position_ned_message(
            self.boot_ms(now), p[0], p[1], p[2], v[0], v[1], v[2])

    def global_position_int(self, now: float) -> Any:
        st = self.fc.state
        geo = self.ned_to_geo(st.position_ned_m)
        v = st.velocity_ned_m_s
        hdg = round(math.degrees(st.yaw_rad) % 360.0 * 100) % 36000
        return mavlink.MAVLink_global_position_int_message(
            self.boot_ms(now), round(geo.lat_deg * 1e7), round(geo.lon_deg * 1e7),
            round(geo.alt_m * 1000), round(st.alt_m * 1000),
            round(v[0] * 100), round(v[1] * 100), round(v[2] * 100), hdg)

    def mission_current(self, now: float) -> Any:
        fc = self.fc
        total = self.mission_total()
        if total == 0:
            state = 1
        elif fc.mission_finished:
            state = 5
        elif fc.mode is Mode.MISSION:
            state = 3
        else:
            state = 2
        return mavlink.MAVLink_mission_current_message(fc.mission_current, total, state, 0)

    def vfr_hud(self, now: float) -> Any:
        st = self.fc.state
        throttle = 0 if not st.armed else (15 if st.on_ground else 50)
        hdg = round(math.degrees(st.yaw_rad)) % 360
        return mavlink.MAVLink_vfr_hud_message(
            st.ground_speed_m_s, st.ground_speed_m_s, hdg, throttle,
            self.home.alt_m + st.alt_m, -st.velocity_ned_m_s[2])

    def battery_status(self, now: float) -> Any:
        st = self.fc.state
        af = st.airframe
        cell_mv = int(st.battery_voltage_v / af.cells * 1000)
        voltages = [cell_mv] * af.cells + [65535] * (10 - af.cells)
        used_mah = int(st.energy_used_wh / (3.7 * af.cells) * 1000)
        energy_hj = int(st.energy_used_wh * 36)
        remaining_s = 0
        if st.power_w > 1.0:
            remaining_s = int(st.battery_remaining * af.battery_capacity_wh * 3600 / st.power_w)
        return mavlink.MAVLink_battery_status_message(
            0, mavlink.MAV_BATTERY_FUNCTION_ALL, mavlink.MAV_BATTERY_TYPE_LIPO, 32767, voltages,
            int(st.battery_current_a * 100), used_mah, energy_hj,
            round(st.battery_remaining * 100), remaining_s,
            mavlink.MAV_BATTERY_CHARGE_STATE_OK, [0, 0, 0, 0], 0, 0)

    def autopilot_version(self, now: float) -> Any:
        caps = _CAPABILITIES | (
            mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE if self.flavour.param_bytewise
            else mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST)
        return mavlink.MAVLink_autopilot_version_message(
            caps, self.flavour.flight_sw_version, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0x26AC,
            0x0011, 0x5349_544C_0000 + self.system_id, [0] * 18)

    def home_position(self, now: float) -> Any:
        home = self.home
        return mavlink.MAVLink_home_position_message(
            round(home.lat_deg * 1e7), round(home.lon_deg * 1e7),
            round(home.alt_m * 1000), 0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0,
            int((self.boot_unix_s + now) * 1e6))

    def extended_sys_state(self, now: float) -> Any:
        return mavlink.MAVLink_extended_sys_state_message(0, self.fc.landed_state)
