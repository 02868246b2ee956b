"""Realistic parameter sets for the two flavours, generated from small tables.

Names, defaults and types follow ArduCopter 4.5 and PX4 1.15 (their parameter reference
pages); values the simulation reads are listed first in :mod:`sitl.vehicle.flavour`, these
tables add the hundreds a client may read or list (stream rates, battery and fence limits,
servo and RC calibration), so a client that reads ``BATT_LOW_VOLT`` or lists everything sees
a table of the size and shape a real autopilot sends.
"""

from __future__ import annotations

from collections.abc import Iterable

ParamRow = tuple[str, float, int]
"""(name, default, MAV_PARAM_TYPE): :mod:`sitl.vehicle.flavour` turns rows into ParamSpecs."""

# MAV_PARAM_TYPE values (the same as in sitl.vehicle.flavour, which imports this module)
PARAM_INT8 = 2
PARAM_INT16 = 4
PARAM_INT32 = 6
PARAM_REAL32 = 9

__all__ = ["ParamRow", "ardupilot_extra_params", "px4_extra_params"]

_I8, _I16, _I32, _F = PARAM_INT8, PARAM_INT16, PARAM_INT32, PARAM_REAL32

# ArduPilot SRn_* stream groups and their default rate on serial 0 (Hz).
_AP_STREAMS = ("RAW_SENS", "EXT_STAT", "RC_CHAN", "RAW_CTRL", "POSITION", "EXTRA1", "EXTRA2",
               "EXTRA3", "PARAMS", "ADSB")

_AP_SCALARS: tuple[ParamRow, ...] = (
    ("FORMAT_VERSION", 120, _I16), ("SYSID_MYGCS", 255, _I16), ("SYSID_ENFORCE", 0, _I8),
    ("PILOT_THR_FILT", 0.0, _F), ("PILOT_THR_BHV", 0, _I16), ("PILOT_SPEED_UP", 250, _I16),
    ("PILOT_SPEED_DN", 0, _I16), ("PILOT_ACCEL_Z", 250, _I16), ("PILOT_Y_RATE", 202.5, _F),
    ("THR_DZ", 100, _I16), ("FLTMODE_CH", 5, _I8), ("INITIAL_MODE", 0, _I8),
    ("ANGLE_MAX", 3000, _I16), ("LOIT_SPEED", 1250.0, _F), ("LOIT_ACC_MAX", 500.0, _F),
    ("LOIT_BRK_ACCEL", 250.0, _F), ("LOIT_BRK_DELAY", 1.0, _F), ("LOIT_ANG_MAX", 0.0, _F),
    ("WPNAV_ACCEL_Z", 100.0, _F), ("WPNAV_RFND_USE", 1, _I8), ("WPNAV_JERK", 1.0, _F),
    ("WP_YAW_BEHAVIOR", 2, _I8), ("WP_NAVALT_MIN", 0.0, _F),
    ("LAND_ALT_LOW", 1000, _I16), ("LAND_REPOSITION", 1, _I8),
    ("RTL_SPEED", 0, _I16), ("RTL_ALT_FINAL", 0, _I16), ("RTL_LOIT_TIME", 5000, _I32),
    ("RTL_CLIMB_MIN", 0, _I16), ("RTL_CONE_SLOPE", 3.0, _F), ("RTL_ALT_TYPE", 0, _I8),
    ("RTL_OPTIONS", 0, _I32),
    ("ARMING_RUDDER", 2, _I8), ("ARMING_ACCTHRESH", 0.75, _F), ("ARMING_MIS_ITEMS", 0, _I32),
    ("ARMING_OPTIONS", 0, _I32), ("ARMING_REQUIRE", 1, _I8),
    ("BATT_LOW_VOLT", 10.5, _F), ("BATT_CRT_VOLT", 0.0, _F), ("BATT_LOW_MAH", 0.0, _F),
    ("BATT_CRT_MAH", 0.0, _F), ("BATT_FS_LOW_ACT", 0, _I8), ("BATT_FS_CRT_ACT", 0, _I8),
    ("BATT_FS_VOLTSRC", 0, _I8), ("BATT_LOW_TIMER", 10, _I8), ("BATT_ARM_VOLT", 0.0, _F),
    ("BATT_ARM_MAH", 0, _I32), ("BATT_VOLT_PIN", 13, _I8), ("BATT_CURR_PIN", 12, _I8),
    ("BATT_VOLT_MULT", 10.1, _F), ("BATT_AMP_PERVLT", 17.0, _F), ("BATT_AMP_OFFSET", 0.0, _F),
    ("BATT_SERIAL_NUM", -1, _I32), ("BATT_OPTIONS", 0, _I32),
    ("FENCE_ENABLE", 0, _I8), ("FENCE_TYPE", 7, _I8), ("FENCE_ACTION", 1, _I8),
    ("FENCE_ALT_MAX", 100.0, _F), ("FENCE_ALT_MIN", -10.0, _F), ("FENCE_RADIUS", 300.0, _F),
    ("FENCE_MARGIN", 2.0, _F), ("FENCE_TOTAL", 0, _I8), ("FENCE_RET_RALLY", 0, _I8),
    ("FENCE_AUTOENABLE", 0, _I8), ("FENCE_OPTIONS", 0, _I16),
    ("FS_THR_ENABLE", 1, _I8), ("FS_THR_VALUE", 975, _I16), ("FS_OPTIONS", 16, _I32),
    ("FS_EKF_ACTION", 1, _I8), ("FS_EKF_THRESH", 0.8, _F), ("FS_CRASH_CHECK", 1, _I8),
    ("FS_VIBE_ENABLE", 1, _I8), ("FS_DR_ENABLE", 2, _I8), ("FS_DR_TIMEOUT", 30, _I16),
    ("FS_GCS_TIMEOUT", 5.0, _F),
    ("GPS_TYPE", 1, _I8), ("GPS_TYPE2", 0, _I8), ("GPS_AUTO_CONFIG", 1, _I8),
    ("GPS_AUTO_SWITCH", 1, _I8), ("GPS_MIN_ELEV", -100, _I8), ("GPS_NAVFILTER", 8, _I8),
    ("GPS_RATE_MS", 200, _I16), ("GPS_HDOP_GOOD", 140, _I16), ("GPS_GNSS_MODE", 0, _I8),
    ("AHRS_EKF_TYPE", 3, _I8), ("AHRS_GPS_USE", 1, _I8), ("AHRS_ORIENTATION", 0, _I8),
    ("AHRS_GPS_MINSATS", 6, _I8), ("EK2_ENABLE", 0, _I8), ("EK3_ENABLE", 1, _I8),
    ("EK3_IMU_MASK", 3, _I8), ("EK3_GPS_CHECK", 31, _I8), ("EK3_SRC1_POSXY", 3, _I8),
    ("EK3_SRC1_VELXY", 3, _I8), ("EK3_SRC1_POSZ", 1, _I8), ("EK3_SRC1_VELZ", 3, _I8),
    ("EK3_SRC1_YAW", 1, _I8), ("EK3_CHECK_SCALE", 100, _I16),
    ("COMPASS_ENABLE", 1, _I8), ("COMPASS_USE", 1, _I8), ("COMPASS_AUTODEC", 1, _I8),
    ("COMPASS_DEC", 0.0, _F), ("INS_GYRO_FILTER", 20, _I16), ("INS_ACCEL_FILTER", 20, _I16),
    ("INS_USE", 1, _I8), ("INS_FAST_SAMPLE", 1, _I8),
    ("MOT_SPIN_ARM", 0.1, _F), ("MOT_SPIN_MIN", 0.15, _F), ("MOT_SPIN_MAX", 0.95, _F),
    ("MOT_PWM_MIN", 1000, _I16), ("MOT_PWM_MAX", 2000, _I16), ("MOT_PWM_TYPE", 0, _I8),
    ("MOT_THST_HOVER", 0.35, _F), ("MOT_HOVER_LEARN", 2, _I8), ("MOT_BAT_VOLT_MAX", 0.0, _F),
    ("MOT_BAT_VOLT_MIN", 0.0, _F), ("FRAME_TYPE", 1, _I8),
    ("ATC_ANG_RLL_P", 4.5, _F), ("ATC_ANG_PIT_P", 4.5, _F), ("ATC_ANG_YAW_P", 4.5, _F),
    ("ATC_RAT_RLL_P", 0.135, _F), ("ATC_RAT_RLL_I", 0.135, _F), ("ATC_RAT_RLL_D", 0.0036, _F),
    ("ATC_RAT_PIT_P", 0.135, _F), ("ATC_RAT_PIT_I", 0.135, _F), ("ATC_RAT_PIT_D", 0.0036, _F),
    ("ATC_RAT_YAW_P", 0.18, _F), ("ATC_RAT_YAW_I", 0.018, _F), ("ATC_ACCEL_R_MAX", 110000.0, _F),
    ("ATC_ACCEL_P_MAX", 110000.0, _F), ("ATC_ACCEL_Y_MAX", 27000.0, _F),
    ("PSC_POSXY_P", 1.0, _F), ("PSC_VELXY_P", 2.0, _F), ("PSC_VELXY_I", 1.0, _F),
    ("PSC_POSZ_P", 1.0, _F), ("PSC_VELZ_P", 5.0, _F), ("PSC_ACCZ_P", 0.5, _F),
    ("PSC_ACCZ_I", 1.0, _F),
    ("CAM1_TYPE", 0, _I8), ("CAM1_DURATION", 0.0, _F), ("CAM1_TRIGG_DIST", 0.0, _F),
    ("RELAY1_FUNCTION", 1, _I8), ("RELAY1_PIN", 13, _I8), ("RELAY2_FUNCTION", 0, _I8),
    ("RELAY2_PIN", -1, _I8), ("SERIAL0_BAUD", 115, _I32), ("SERIAL0_PROTOCOL", 2, _I8),
    ("SERIAL1_BAUD", 57, _I32), ("SERIAL1_PROTOCOL", 2, _I8), ("SERIAL2_BAUD", 57, _I32),
    ("SERIAL2_PROTOCOL", 2, _I8), ("TELEM_DELAY", 0, _I8), ("GCS_PID_MASK", 0, _I16),
    ("LOG_BITMASK", 176126, _I32), ("LOG_BACKEND_TYPE", 1, _I8), ("LOG_DISARMED", 0, _I8),
    ("BRD_SAFETY_DEFLT", 0, _I8), ("BRD_SAFETY_MASK", 0, _I32), ("SCHED_LOOP_RATE", 400, _I16),
    ("TERRAIN_ENABLE", 1, _I8), ("TERRAIN_SPACING", 100, _I16), ("AVOID_ENABLE", 3, _I8),
    ("PRX1_TYPE", 0, _I8), ("RNGFND1_TYPE", 0, _I8), ("FLOW_TYPE", 0, _I8),
    ("SIM_SPEEDUP", 1.0, _F), ("SIM_GPS_DISABLE", 0, _I8), ("SIM_BATT_VOLTAGE", 12.6, _F),
    ("STAT_RUNTIME", 0, _I32), ("STAT_FLTTIME", 0, _I32), ("STAT_BOOTCNT", 1, _I16),
    # ADS-B in and avoidance (AP_ADSB, AP_Avoidance; read by sitl.vehicle.traffic)
    ("ADSB_TYPE", 0, _I8), ("ADSB_LIST_MAX", 25, _I16), ("ADSB_LIST_RADIUS", 2000, _I32),
    ("ADSB_LIST_ALT", 0, _I16), ("ADSB_ICAO_ID", 0, _I32), ("AVD_ENABLE", 0, _I8),
    ("AVD_F_ACTION", 1, _I8), ("AVD_F_DIST_XY", 100, _I16), ("AVD_F_DIST_Z", 100, _I16),
    ("AVD_F_TIME", 30, _I8), ("AVD_W_ACTION", 1, _I8), ("AVD_W_DIST_XY", 300, _I16),
    ("AVD_W_DIST_Z", 300, _I16), ("AVD_W_TIME", 30, _I8),
)

_AP_SERVO_FUNCTIONS = (33, 34, 35, 36)  # Motor1..Motor4 on SERVO1..4 (quad X)

_PX4_SCALARS: tuple[ParamRow, ...] = (
    ("SYS_AUTOCONFIG", 0, _I32), ("SYS_MC_EST_GROUP", 2, _I32), ("SYS_HAS_GPS", 1, _I32),
    ("SYS_HAS_MAG", 1, _I32), ("SYS_HAS_BARO", 1, _I32),
    ("MAV_COMP_ID", 1, _I32), ("MAV_TYPE", 2, _I32), ("MAV_PROTO_VER", 0, _I32),
    ("MAV_0_CONFIG", 300, _I32), ("MAV_0_MODE", 0, _I32), ("MAV_0_RATE", 1200, _I32),
    ("MAV_0_FORWARD", 1, _I32), ("MAV_1_CONFIG", 0, _I32), ("MAV_1_MODE", 2, _I32),
    ("MAV_1_RATE", 0, _I32), ("MAV_1_FORWARD", 0, _I32), ("MAV_2_CONFIG", 0, _I32),
    ("COM_ARM_WO_GPS", 1, _I32), ("COM_RC_LOSS_T", 0.5, _F), ("COM_DL_LOSS_T", 10, _I32),
    ("COM_LOW_BAT_ACT", 0, _I32), ("COM_POS_FS_DELAY", 1, _I32), ("COM_HOME_H_T", 5.0, _F),
    ("COM_HOME_V_T", 10.0, _F), ("COM_OBL_RC_ACT", 0, _I32), ("COM_ARM_MAG_ANG", 60, _I32),
    ("COM_ARM_IMU_ACC", 0.7, _F), ("COM_ARM_EKF_POS", 0.5, _F), ("COM_ARM_EKF_VEL", 0.5, _F),
    ("COM_ARM_SWISBTN", 0, _I32), ("COM_ARMABLE", 1, _I32), ("COM_KILL_DISARM", 5.0, _F),
    ("COM_FLTMODE1", -1, _I32), ("COM_FLTMODE2", -1, _I32), ("COM_FLTMODE3", -1, _I32),
    ("COM_FLTMODE4", -1, _I32), ("COM_FLTMODE5", -1, _I32), ("COM_FLTMODE6", -1, _I32),
    ("COM_FLTT_LOW_ACT", 3, _I32), ("COM_POSCTL_NAVL", 0, _I32), ("COM_PREARM_MODE", 0, _I32),
    ("COM_TAKEOFF_ACT", 0, _I32), ("COM_QC_ACT", 0, _I32), ("COM_WIND_WARN", -1.0, _F),
    ("GF_ACTION", 2, _I32), ("GF_MAX_HOR_DIST", 0.0, _F), ("GF_MAX_VER_DIST", 0.0, _F),
    ("GF_SOURCE", 0, _I32), ("GF_PREDICT", 1, _I32), ("GF_COUNT", -1, _I32),
    ("BAT1_V_EMPTY", 3.6, _F), ("BAT1_V_CHARGED", 4.05, _F), ("BAT1_V_LOAD_DROP", 0.1, _F),
    ("BAT1_R_INTERNAL", 0.005, _F), ("BAT1_SOURCE", 0, _I32), ("BAT_LOW_THR", 0.15, _F),
    ("BAT_CRIT_THR", 0.07, _F), ("BAT_EMERGEN_THR", 0.05, _F), ("BAT_AVRG_CURRENT", 15.0, _F),
    ("EKF2_EN", 1, _I32), ("EKF2_GPS_CTRL", 7, _I32), ("EKF2_HGT_REF", 1, _I32),
    ("EKF2_REQ_EPH", 3.0, _F), ("EKF2_REQ_EPV", 5.0, _F), ("EKF2_REQ_NSATS", 6, _I32),
    ("EKF2_REQ_PDOP", 2.5, _F), ("EKF2_REQ_SACC", 0.5, _F), ("EKF2_REQ_GPS_H", 10.0, _F),
    ("EKF2_GPS_DELAY", 110.0, _F), ("EKF2_MAG_TYPE", 0, _I32), ("EKF2_BARO_CTRL", 1, _I32),
    ("EKF2_IMU_CTRL", 7, _I32), ("EKF2_DRAG_CTRL", 0, _I32), ("EKF2_RNG_CTRL", 1, _I32),
    ("MPC_TKO_SPEED", 1.5, _F), ("MPC_TKO_RAMP_T", 3.0, _F), ("MPC_LAND_ALT1", 10.0, _F),
    ("MPC_LAND_ALT2", 5.0, _F), ("MPC_LAND_CRWL", 0.3, _F), ("MPC_XY_VEL_P_ACC", 1.8, _F),
    ("MPC_XY_P", 0.95, _F), ("MPC_Z_P", 1.0, _F), ("MPC_Z_VEL_P_ACC", 4.0, _F),
    ("MPC_THR_HOVER", 0.5, _F), ("MPC_THR_MIN", 0.12, _F), ("MPC_THR_MAX", 1.0, _F),
    ("MPC_TILTMAX_AIR", 45.0, _F), ("MPC_MAN_TILT_MAX", 35.0, _F), ("MPC_YAWRAUTO_MAX", 45.0, _F),
    ("MPC_POS_MODE", 4, _I32), ("MPC_ALT_MODE", 0, _I32), ("MPC_JERK_AUTO", 4.0, _F),
    ("MPC_ACC_UP_MAX", 4.0, _F), ("MPC_ACC_DOWN_MAX", 3.0, _F), ("MPC_HOLD_DZ", 0.1, _F),
    ("MC_ROLL_P", 6.5, _F), ("MC_PITCH_P", 6.5, _F), ("MC_YAW_P", 2.8, _F),
    ("MC_ROLLRATE_P", 0.15, _F), ("MC_ROLLRATE_I", 0.2, _F), ("MC_ROLLRATE_D", 0.003, _F),
    ("MC_PITCHRATE_P", 0.15, _F), ("MC_PITCHRATE_I", 0.2, _F), ("MC_PITCHRATE_D", 0.003, _F),
    ("MC_YAWRATE_P", 0.2, _F), ("MC_YAWRATE_I", 0.1, _F), ("MC_AIRMODE", 0, _I32),
    ("NAV_MC_ALT_RAD", 0.8, _F), ("NAV_LOITER_RAD", 80.0, _F), ("NAV_FORCE_VT", 1, _I32),
    ("MIS_DIST_1WP", 900.0, _F), ("MIS_YAW_TMT", -1.0, _F), ("MIS_YAW_ERR", 12.0, _F),
    ("RTL_DESCEND_ALT", 30.0, _F), ("RTL_LAND_DELAY", 0.0, _F), ("RTL_MIN_DIST", 10.0, _F),
    ("RTL_TYPE", 0, _I32), ("RTL_CONE_ANG", 45, _I32),
    ("CAM_CAP_FBACK", 0, _I32), ("TRIG_MODE", 0, _I32), ("TRIG_INTERFACE", 4, _I32),
    ("GPS_1_CONFIG", 201, _I32), ("GPS_1_PROTOCOL", 1, _I32), ("GPS_1_GNSS", 0, _I32),
    ("GPS_YAW_OFFSET", 0.0, _F), ("SENS_BOARD_ROT", 0, _I32), ("SENS_EN_GPSSIM", 0, _I32),
    ("SIH_IXX", 0.025, _F), ("SIH_IYY", 0.025, _F), ("SIH_IZZ", 0.03, _F),
    ("SIH_MASS", 1.0, _F), ("SIH_T_MAX", 5.0, _F), ("SIH_Q_MAX", 0.1, _F),
    ("SIH_LOC_LAT0", 473977420, _I32), ("SIH_LOC_LON0", 85455940, _I32),
    ("SIH_LOC_H0", 489.4, _F), ("SIH_VEHICLE_TYPE", 0, _I32),
    ("SDLOG_MODE", 0, _I32), ("SDLOG_PROFILE", 1, _I32), ("CBRK_SUPPLY_CHK", 894281, _I32),
    ("CBRK_IO_SAFETY", 22027, _I32), ("CBRK_USB_CHK", 197848, _I32),
    ("LNDMC_Z_VEL_MAX", 0.5, _F), ("LNDMC_XY_VEL_MAX", 1.5, _F), ("LNDMC_ALT_MAX", -1.0, _F),
    ("CA_AIRFRAME", 0, _I32), ("CA_ROTOR_COUNT", 4, _I32),
    # traffic avoidance (navigator; read by sitl.vehicle.traffic)
    ("NAV_TRAFF_AVOID", 1, _I32), ("NAV_TRAFF_A_RADU", 10.0, _F),
    ("NAV_TRAFF_A_RADM", 500.0, _F),
)


def _new(rows: Iterable[ParamRow], taken: set[str]) -> tuple[ParamRow, ...]:
    out = []
    for row in rows:
        if row[0] not in taken:
            taken.add(row[0])
            out.append(row)
    return tuple(out)


def ardupilot_extra_params(taken: set[str]) -> tuple[ParamRow, ...]:
    """ArduCopter-like parameters beyond those the simulation uses (``taken``)."""
    rows: list[ParamRow] = list(_AP_SCALARS)
    for n in range(7):
        rows += [(f"SR{n}_{s}", 4 if n == 0 and s in ("POSITION", "EXTRA1") else 0, _I16)
                 for s in _AP_STREAMS]
    for mode in range(1, 7):
        rows.append((f"FLTMODE{mode}", 0, _I8))
    for ch in range(1, 17):
        function = _AP_SERVO_FUNCTIONS[ch - 1] if ch <= 4 else 0
        rows += [(f"SERVO{ch}_FUNCTION", function, _I16), (f"SERVO{ch}_MIN", 1100, _I16),
                 (f"SERVO{ch}_MAX", 1900, _I16), (f"SERVO{ch}_TRIM", 1500, _I16),
                 (f"SERVO{ch}_REVERSED", 0, _I8)]
    for ch in range(1, 17):
        rows += [(f"RC{ch}_MIN", 1100, _I16), (f"RC{ch}_MAX", 1900, _I16),
                 (f"RC{ch}_TRIM", 1500, _I16), (f"RC{ch}_REVERSED", 0, _I8),
                 (f"RC{ch}_DZ", 30 if ch <= 4 else 0, _I16), (f"RC{ch}_OPTION", 0, _I16)]
    return _new(rows, taken)


def px4_extra_params(taken: set[str]) -> tuple[ParamRow, ...]:
    """PX4-like parameters beyond those the simulation uses (``taken``)."""
    rows: list[ParamRow] = list(_PX4_SCALARS)
    for ch in range(1, 9):
        rows += [(f"PWM_MAIN_FUNC{ch}", 101 + ch - 1 if ch <= 4 else 0, _I32),
                 (f"PWM_MAIN_MIN{ch}", 1000, _I32), (f"PWM_MAIN_MAX{ch}", 2000, _I32),
                 (f"PWM_MAIN_DIS{ch}", 900, _I32), (f"PWM_MAIN_FAIL{ch}", -1, _I32)]
    for ch in range(1, 19):
        rows += [(f"RC{ch}_MIN", 1000.0, _F), (f"RC{ch}_MAX", 2000.0, _F),
                 (f"RC{ch}_TRIM", 1500.0, _F), (f"RC{ch}_REV", 1.0, _F),
                 (f"RC{ch}_DZ", 10.0, _F)]
    return _new(rows, taken)
