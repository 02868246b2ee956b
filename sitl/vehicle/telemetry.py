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
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sitl.geo import Enu, GeoPoint, geo_from_enu
from sitl.vehicle.autopilot import FlightController
from sitl.vehicle.flavour import Flavour, Mode
from sitl.vehicle.physics import gps_reading
from sitl.vehicle.stream_tables import (
    ARDUPILOT_ONLY,
    MSG_AHRS,
    MSG_AHRS2,
    MSG_ATTITUDE,
    MSG_AUTOPILOT_VERSION,
    MSG_BATTERY_STATUS,
    MSG_EKF_STATUS_REPORT,
    MSG_ESTIMATOR_STATUS,
    MSG_EXTENDED_SYS_STATE,
    MSG_FENCE_STATUS,
    MSG_GLOBAL_POSITION_INT,
    MSG_GPS_GLOBAL_ORIGIN,
    MSG_GPS_RAW_INT,
    MSG_HEARTBEAT,
    MSG_HOME_POSITION,
    MSG_LOCAL_POSITION_NED,
    MSG_MEMINFO,
    MSG_MISSION_CURRENT,
    MSG_NAV_CONTROLLER_OUTPUT,
    MSG_POWER_STATUS,
    MSG_RAW_IMU,
    MSG_RC_CHANNELS,
    MSG_SCALED_PRESSURE,
    MSG_SERVO_OUTPUT_RAW,
    MSG_SYS_STATUS,
    MSG_SYSTEM_TIME,
    MSG_VFR_HUD,
    MSG_VIBRATION,
    MSG_WIND,
)

__all__ = ["Telemetry"]



_SENSOR_GPS = 32
_SENSOR_AHRS = 1 << 21
_SENSOR_PREARM = 1 << 28
_EKF_ALWAYS = 1 | 2 | 4 | 32  # attitude, horizontal and vertical velocity, vertical position
_EKF_POSITION = 8 | 16 | 256 | 512  # (predicted) horizontal position, relative and absolute
_EKF_CONST_POS_MODE = 128
_EKF_POS_VERT_AGL = 64
# PX4 SIH (main ddb9a5d0b9, measured; docs/sitl.md): 229 before the GNSS is fused (attitude,
# vertical velocity and position, height above ground, constant position), 1023 on the ground
# with it (ekf2 sets CONST_POS_MODE whenever the vehicle is at rest), 831 just after arming,
# 895 in the air (and in the first seconds after landing).
_PX4_NO_FIX = 1 | 4 | 32 | _EKF_POS_VERT_AGL | _EKF_CONST_POS_MODE
_PX4_FLYING = _EKF_ALWAYS | _EKF_POSITION | _EKF_POS_VERT_AGL

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
        builders: dict[int, Callable[[float], Any]] = {
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
            MSG_RAW_IMU: self.raw_imu,
            MSG_SCALED_PRESSURE: self.scaled_pressure,
            MSG_SERVO_OUTPUT_RAW: self.servo_output_raw,
            MSG_GPS_GLOBAL_ORIGIN: self.gps_global_origin,
            MSG_NAV_CONTROLLER_OUTPUT: self.nav_controller_output,
            MSG_RC_CHANNELS: self.rc_channels,
            MSG_POWER_STATUS: self.power_status,
            MSG_MEMINFO: self.meminfo,
            MSG_FENCE_STATUS: self.fence_status,
            MSG_AHRS: self.ahrs,
            MSG_WIND: self.wind,
            MSG_AHRS2: self.ahrs2,
            MSG_EKF_STATUS_REPORT: self.ekf_status_report,
            MSG_ESTIMATOR_STATUS: self.estimator_status,
            MSG_VIBRATION: self.vibration,
        }
        if flavour.name == "px4":
            for msg_id in ARDUPILOT_ONLY:
                del builders[msg_id]
        else:
            del builders[MSG_ESTIMATOR_STATUS]
        self.builders: Mapping[int, Callable[[float], Any]] = builders

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
        health = _SENSORS
        if not self.fc.gps_has_fix:  # GPS present but unhealthy
            health &= ~_SENSOR_GPS
        if not self.fc.has_fix:  # no position estimate: pre-arm checks failing
            health &= ~_SENSOR_PREARM
        return mavlink.MAVLink_sys_status_message(
            _SENSORS, _SENSORS, health, 250, int(st.battery_voltage_v * 1000),
            int(st.battery_current_a * 100), round(st.battery_remaining * 100),
            0, 0, 0, 0, 0, 0)

    def system_time(self, now: float) -> Any:
        # ArduCopter 4.5 SITL (measured 2026-12-04): time_unix_usec 0 until its GPS has the
        # time, then UTC (3.2 s behind the host's clock there). PX4 sends its own clock.
        unknown = self.flavour.name != "px4" and not self.fc.gps_has_fix
        return mavlink.MAVLink_system_time_message(
            0 if unknown else int((self.boot_unix_s + now) * 1e6), self.boot_ms(now))

    def gps_raw_int(self, now: float) -> Any:
        if not self.fc.gps_has_fix:
            # A receiver still searching: NO_FIX at 0/0, accuracies unknown (UINT16_MAX).
            return mavlink.MAVLink_gps_raw_int_message(
                int((self.boot_unix_s + now) * 1e6), 1, 0, 0, 0, 65535, 65535, 0, 65535,
                min(3, int(now)), 0, 0, 0, 0, 0, 0)
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

    def global_position_int(self, now: float) -> Any | None:
        st = self.fc.state
        if not self.fc.gps_has_fix:
            if self.flavour.name == "px4":
                return None  # PX4 publishes no global position before the estimator has one
            # ArduPilot sends its (empty) location: lat/lon 0/0, altitude relative to boot.
            return mavlink.MAVLink_global_position_int_message(
                self.boot_ms(now), 0, 0, round(st.alt_m * 1000), round(st.alt_m * 1000),
                0, 0, 0, round(math.degrees(st.yaw_rad) % 360.0 * 100) % 36000)
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

    def home_position(self, now: float) -> Any | None:
        """HOME_POSITION, or None before home is set (no fix yet)."""
        if not self.fc.has_fix:
            return None
        h = self.fc.home_ned_m
        home = self.ned_to_geo(h)
        return mavlink.MAVLink_home_position_message(
            round(home.lat_deg * 1e7), round(home.lon_deg * 1e7),
            round(home.alt_m * 1000), h[0], h[1], h[2], [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0,
            int((self.boot_unix_s + now) * 1e6))

    def gps_global_origin(self, now: float) -> Any | None:
        if not self.fc.has_fix:
            return None
        o = self.home
        return mavlink.MAVLink_gps_global_origin_message(
            round(o.lat_deg * 1e7), round(o.lon_deg * 1e7), round(o.alt_m * 1000),
            int((self.boot_unix_s + now) * 1e6))

    def raw_imu(self, now: float) -> Any:
        st = self.fc.state
        # Level and still: 1 g down (mG), no rotation; the magnetometer sees a fixed field.
        return mavlink.MAVLink_raw_imu_message(
            int(now * 1e6), round(-st.pitch_rad * 1000), round(st.roll_rad * 1000), -1000,
            0, 0, round(st.yaw_rate_rad_s * 1000), 200, 0, 400)

    def scaled_pressure(self, now: float) -> Any:
        alt = self.home.alt_m + self.fc.state.alt_m
        press_hpa = 1013.25 * (1.0 - 2.25577e-5 * alt) ** 5.25588
        return mavlink.MAVLink_scaled_pressure_message(self.boot_ms(now), press_hpa, 0.0, 2500)

    def servo_output_raw(self, now: float) -> Any:
        st = self.fc.state
        motor = 1000 if not st.armed else (1150 if st.on_ground else 1500)
        pwm = [motor] * 4 + self.fc.servo_pwm[4:]
        return mavlink.MAVLink_servo_output_raw_message(int(now * 1e6) & 0xFFFFFFFF, 0, *pwm)

    def rc_channels(self, now: float) -> Any:
        # Sticks centred, throttle low, switches low: what a bench transmitter sends.
        chans = [1500, 1500, 1000, 1500] + [1000] * 4 + [0] * 10
        return mavlink.MAVLink_rc_channels_message(self.boot_ms(now), 8, *chans, 255)

    def nav_controller_output(self, now: float) -> Any:
        fc = self.fc
        st = fc.state
        p = st.position_ned_m
        target = st.setpoint.position_ned_m or p
        dn, de = target[0] - p[0], target[1] - p[1]
        bearing = round(math.degrees(math.atan2(de, dn))) % 360 if math.hypot(dn, de) > 0.1 \
            else round(math.degrees(st.yaw_rad)) % 360
        return mavlink.MAVLink_nav_controller_output_message(
            math.degrees(st.roll_rad), math.degrees(st.pitch_rad), bearing, bearing,
            min(round(math.hypot(dn, de)), 65535), p[2] - target[2], 0.0, 0.0)

    def power_status(self, now: float) -> Any:
        return mavlink.MAVLink_power_status_message(5000, 0, 1 | 2)

    def meminfo(self, now: float) -> Any:
        return mavlink.MAVLink_meminfo_message(0, 65535, 131072)

    def fence_status(self, now: float) -> Any | None:
        """ArduPilot streams FENCE_STATUS only while a fence is enabled."""
        if self.fc.params.get("FENCE_ENABLE") < 0.5:
            return None
        return mavlink.MAVLink_fence_status_message(0, 0, 0, 0, 0)

    def ahrs(self, now: float) -> Any:
        return mavlink.MAVLink_ahrs_message(0.0, 0.0, 0.0, 0.0, 0.0, 0.01, 0.01)

    def ahrs2(self, now: float) -> Any:
        st = self.fc.state
        if self.fc.has_fix:
            geo = self.ned_to_geo(st.position_ned_m)
            lat, lon = round(geo.lat_deg * 1e7), round(geo.lon_deg * 1e7)
        else:
            lat = lon = 0
        return mavlink.MAVLink_ahrs2_message(st.roll_rad, st.pitch_rad, st.yaw_rad,
                                             self.home.alt_m + st.alt_m, lat, lon)

    def wind(self, now: float) -> Any:
        w = self.fc.state.wind_ned_m_s
        speed = math.hypot(w[0], w[1])
        # WIND.direction is where the wind blows *from*, degrees.
        direction = math.degrees(math.atan2(-w[1], -w[0])) % 360.0 if speed > 0 else 0.0
        return mavlink.MAVLink_wind_message(direction, speed, -w[2])

    def _estimator_flags(self) -> int:
        if self.flavour.name == "px4":
            if not self.fc.has_fix:
                return _PX4_NO_FIX
            at_rest = self.fc.state.on_ground and not self.fc.state.armed
            return _PX4_FLYING | (_EKF_CONST_POS_MODE if at_rest else 0)
        if self.fc.has_fix:
            return _EKF_ALWAYS | _EKF_POSITION
        return _EKF_ALWAYS | _EKF_CONST_POS_MODE

    def ekf_status_report(self, now: float) -> Any:
        pos_var = 0.02 if self.fc.has_fix else 0.0
        return mavlink.MAVLink_ekf_status_report_message(
            self._estimator_flags(), 0.02, pos_var, 0.01, 0.03, 0.0, 0.0)

    def estimator_status(self, now: float) -> Any:
        ok = self.fc.has_fix
        return mavlink.MAVLink_estimator_status_message(
            int(now * 1e6), self._estimator_flags(), 0.05, 0.05 if ok else 0.0, 0.05, 0.05,
            0.0, 0.0, 0.5 if ok else 999.0, 0.8)

    def vibration(self, now: float) -> Any:
        airborne = not self.fc.state.on_ground
        level = 3.0 if airborne else 0.2
        return mavlink.MAVLink_vibration_message(int(now * 1e6), level, level, level * 1.5,
                                                 0, 0, 0)

    def extended_sys_state(self, now: float) -> Any:
        return mavlink.MAVLink_extended_sys_state_message(0, self.fc.landed_state)
