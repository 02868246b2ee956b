"""The two autopilot flavours: their mode numbers, parameters and habits clients must cope with.

Habits (each is a place where stock clients have flavour-specific code paths):

- PX4: telemetry streams flow unrequested; integer parameters travel byte-encoded in
  PARAM_VALUE's float field (MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE); custom_mode is
  ``main_mode << 16 | sub_mode << 24``; NAV_TAKEOFF param7 is AMSL (NaN: MIS_TAKEOFF_ALT);
  mission item 0 is the first waypoint.
- ArduPilot: only HEARTBEAT until streams are requested (SET_MESSAGE_INTERVAL or
  REQUEST_DATA_STREAM); integer params are C-cast to float; custom_mode is the copter mode
  number; no arming in RTL or LAND; takeoff only in GUIDED; mission item 0 is home.
"""

from __future__ import annotations

import enum
import struct
from collections.abc import Callable
from dataclasses import dataclass
from types import MappingProxyType
from typing import Literal

from sitl.vehicle.param_tables import ParamRow, ardupilot_extra_params, px4_extra_params

__all__ = [
    "ARDUPILOT",
    "FLAVOURS",
    "PX4",
    "Flavour",
    "Mode",
    "ParamKind",
    "ParamSpec",
    "decode_param_value",
    "encode_param_value",
]


class Mode(enum.Enum):
    """What the simulated flight controller does; each flavour names these its own way."""

    MANUAL = "manual"
    """Stabilised/altitude/manual modes: with no sticks in the simulation it holds position."""
    POSITION = "position"
    HOLD = "hold"
    TAKEOFF = "takeoff"
    LAND = "land"
    RTL = "rtl"
    MISSION = "mission"
    GUIDED = "guided"
    """PX4 OFFBOARD / ArduPilot GUIDED: follows SET_POSITION_TARGET_*."""


# MAV_PARAM_TYPE values
PARAM_INT8 = 2
PARAM_INT16 = 4
PARAM_INT32 = 6
PARAM_REAL32 = 9

ParamKind = Literal["int", "float"]


@dataclass(frozen=True, slots=True, kw_only=True)
class ParamSpec:
    """A parameter the vehicle knows: its default and MAVLink type."""

    name: str
    default: float
    param_type: int = PARAM_REAL32

    @property
    def is_int(self) -> bool:
        return self.param_type != PARAM_REAL32


def encode_param_value(value: float, param_type: int, *, bytewise: bool) -> float:
    """The float to put in PARAM_VALUE.param_value (bytewise: int32 bits reinterpreted)."""
    if param_type == PARAM_REAL32 or not bytewise:
        return float(value)
    packed = struct.pack("<i", int(value))
    return float(struct.unpack("<f", packed)[0])


def decode_param_value(raw: float, param_type: int, *, bytewise: bool) -> float:
    """Inverse of :func:`encode_param_value` for PARAM_SET; ints come back as whole floats."""
    if param_type == PARAM_REAL32:
        return float(raw)
    if bytewise:
        return float(struct.unpack("<i", struct.pack("<f", raw))[0])
    return float(round(raw))


@dataclass(frozen=True, slots=True, kw_only=True)
class Flavour:
    """Everything that differs between the PX4-like and the ArduPilot-like vehicle."""

    name: str
    autopilot: int
    """MAV_AUTOPILOT value in HEARTBEAT (12 PX4, 3 ArduPilotMega)."""
    streams_unrequested: bool
    param_bytewise: bool
    mission_item0_is_home: bool
    takeoff_param7_amsl: bool
    takeoff_needs_guided: bool
    unarmable_modes: frozenset[Mode]
    modes: MappingProxyType[Mode, int]
    """Mode -> custom_mode reported in HEARTBEAT."""
    mode_aliases: MappingProxyType[int, Mode]
    """custom_mode accepted in DO_SET_MODE/SET_MODE -> Mode (more names than reported)."""
    params: tuple[ParamSpec, ...]
    initial_mode: Mode
    flight_sw_version: int
    settings: MappingProxyType[str, tuple[str | None, float]]
    """Setting -> (parameter, scale to SI) or (None, constant): how this flavour spells it."""
    min_stream_interval_s: float = 0.003
    """No stream goes out faster than the autopilot's main loop. ArduPilot caps every message
    interval at 0.8 x SCHED_LOOP_RATE (``cap_message_interval``: 3 ms at ArduCopter's 400 Hz)
    and answers a faster SET_MESSAGE_INTERVAL TEMPORARILY_REJECTED. PX4's floor (its mavlink
    thread's loop) is taken as 1 ms here, an assumption, not a measurement."""
    accepted_commands: frozenset[int] = frozenset()
    """Peripheral/auxiliary MAV_CMDs this stack accepts (the rest get UNSUPPORTED)."""
    # Unknown parameter names and indices are dropped by both stacks: ArduPilot 4.5's
    # GCS_Param returns when AP_Param::find fails; PX4 (v1.14 on, and main ddb9a5d0b9 measured
    # in SIH) only logs "unknown param ..." on its own console (PX4_ERR), no STATUSTEXT. Releases
    # from late 2025 on answer with PARAM_ERROR (ArduPilot PR 31062, PX4 PR 25699).

    def custom_mode(self, mode: Mode) -> int:
        return self.modes[mode]

    def mode_from_custom(self, custom_mode: int) -> Mode | None:
        """The mode a client asks for, or None when this flavour has no such mode."""
        return self.mode_aliases.get(custom_mode)


def _px4_mode(main: int, sub: int = 0) -> int:
    return (main << 16) | (sub << 24)


_PX4_MODES = {
    Mode.MANUAL: _px4_mode(1),
    Mode.POSITION: _px4_mode(3),
    Mode.HOLD: _px4_mode(4, 3),
    Mode.TAKEOFF: _px4_mode(4, 2),
    Mode.LAND: _px4_mode(4, 6),
    Mode.RTL: _px4_mode(4, 5),
    Mode.MISSION: _px4_mode(4, 4),
    Mode.GUIDED: _px4_mode(6),
}
_PX4_ALIASES = {v: k for k, v in _PX4_MODES.items()}
_PX4_ALIASES.update({
    _px4_mode(2): Mode.MANUAL,  # ALTCTL
    _px4_mode(5): Mode.MANUAL,  # ACRO
    _px4_mode(7): Mode.MANUAL,  # STABILIZED
    _px4_mode(4, 1): Mode.HOLD,  # AUTO.READY
    _px4_mode(4, 0): Mode.HOLD,
})

_ARDUPILOT_MODES = {
    Mode.MANUAL: 0,  # STABILIZE
    Mode.POSITION: 5,  # LOITER
    Mode.HOLD: 17,  # BRAKE
    Mode.TAKEOFF: 4,  # takeoff happens in GUIDED
    Mode.LAND: 9,
    Mode.RTL: 6,
    Mode.MISSION: 3,  # AUTO
    Mode.GUIDED: 4,
}
_ARDUPILOT_ALIASES = {v: k for k, v in _ARDUPILOT_MODES.items() if k is not Mode.TAKEOFF}
_ARDUPILOT_ALIASES.update({2: Mode.MANUAL, 1: Mode.MANUAL, 16: Mode.POSITION, 21: Mode.RTL})

_PX4_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec(name="SYS_AUTOSTART", default=4001, param_type=PARAM_INT32),
    ParamSpec(name="SYS_HITL", default=0, param_type=PARAM_INT32),
    ParamSpec(name="MAV_SYS_ID", default=1, param_type=PARAM_INT32),
    ParamSpec(name="MIS_TAKEOFF_ALT", default=2.5),
    ParamSpec(name="MPC_XY_CRUISE", default=5.0),
    ParamSpec(name="MPC_XY_VEL_MAX", default=12.0),
    ParamSpec(name="MPC_Z_VEL_MAX_UP", default=3.0),
    ParamSpec(name="MPC_Z_VEL_MAX_DN", default=1.5),
    ParamSpec(name="MPC_ACC_HOR", default=3.0),
    ParamSpec(name="MPC_LAND_SPEED", default=0.7),
    ParamSpec(name="NAV_ACC_RAD", default=2.0),
    ParamSpec(name="RTL_RETURN_ALT", default=30.0),
    ParamSpec(name="COM_DISARM_LAND", default=2.0),
    ParamSpec(name="COM_DISARM_PRFLT", default=10.0),
    ParamSpec(name="COM_OF_LOSS_T", default=1.0),
    ParamSpec(name="COM_RC_IN_MODE", default=1, param_type=PARAM_INT32),
    ParamSpec(name="NAV_DLL_ACT", default=0, param_type=PARAM_INT32),
    ParamSpec(name="NAV_RCL_ACT", default=0, param_type=PARAM_INT32),
    ParamSpec(name="BAT1_N_CELLS", default=4, param_type=PARAM_INT32),
    ParamSpec(name="BAT1_CAPACITY", default=5000.0),
    ParamSpec(name="SIM_WIND_SPD", default=0.0),
    ParamSpec(name="SIM_WIND_DIR", default=0.0),
)

_ARDUPILOT_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec(name="SYSID_THISMAV", default=1, param_type=PARAM_INT16),
    ParamSpec(name="FRAME_CLASS", default=1, param_type=PARAM_INT8),
    ParamSpec(name="ARMING_CHECK", default=1, param_type=PARAM_INT32),
    ParamSpec(name="PILOT_TKOFF_ALT", default=0.0),
    ParamSpec(name="WPNAV_SPEED", default=1000.0),
    ParamSpec(name="WPNAV_SPEED_UP", default=250.0),
    ParamSpec(name="WPNAV_SPEED_DN", default=150.0),
    ParamSpec(name="WPNAV_ACCEL", default=250.0),
    ParamSpec(name="WPNAV_RADIUS", default=200.0),
    ParamSpec(name="LAND_SPEED", default=50, param_type=PARAM_INT16),
    ParamSpec(name="RTL_ALT", default=1500, param_type=PARAM_INT32),
    ParamSpec(name="DISARM_DELAY", default=10, param_type=PARAM_INT8),
    ParamSpec(name="BATT_CAPACITY", default=5000, param_type=PARAM_INT32),
    ParamSpec(name="BATT_MONITOR", default=4, param_type=PARAM_INT8),
    ParamSpec(name="FS_GCS_ENABLE", default=0, param_type=PARAM_INT8),
    ParamSpec(name="SIM_WIND_SPD", default=0.0),
    ParamSpec(name="SIM_WIND_DIR", default=0.0),
    ParamSpec(name="SR0_POSITION", default=0, param_type=PARAM_INT16),
    ParamSpec(name="SR0_EXTRA1", default=0, param_type=PARAM_INT16),
    ParamSpec(name="SR0_EXT_STAT", default=0, param_type=PARAM_INT16),
)

def _with_extras(core: tuple[ParamSpec, ...], extras: Callable[[set[str]], tuple[ParamRow, ...]]
                 ) -> tuple[ParamSpec, ...]:
    """The simulation's own parameters first (stable indices), then the realistic rest."""
    rows = extras({p.name for p in core})
    return core + tuple(ParamSpec(name=n, default=d, param_type=t) for n, d, t in rows)


_PX4_PARAMS = _with_extras(_PX4_PARAMS, px4_extra_params)
_ARDUPILOT_PARAMS = _with_extras(_ARDUPILOT_PARAMS, ardupilot_extra_params)

PX4 = Flavour(
    name="px4",
    min_stream_interval_s=0.001,
    autopilot=12,
    streams_unrequested=True,
    param_bytewise=True,
    mission_item0_is_home=False,
    takeoff_param7_amsl=True,
    takeoff_needs_guided=False,
    unarmable_modes=frozenset({Mode.LAND, Mode.RTL}),
    modes=MappingProxyType(_PX4_MODES),
    mode_aliases=MappingProxyType(_PX4_ALIASES),
    params=_PX4_PARAMS,
    initial_mode=Mode.HOLD,  # PX4 SIH boots in AUTO.LOITER (commander's initial intention)
    flight_sw_version=(1 << 24) | (15 << 16) | (0 << 8) | 255,
    settings=MappingProxyType({
        "cruise_m_s": ("MPC_XY_CRUISE", 1.0),
        "max_speed_h_m_s": ("MPC_XY_VEL_MAX", 1.0),
        "max_speed_up_m_s": ("MPC_Z_VEL_MAX_UP", 1.0),
        "max_speed_down_m_s": ("MPC_Z_VEL_MAX_DN", 1.0),
        "max_accel_m_s2": ("MPC_ACC_HOR", 1.0),
        "takeoff_alt_m": ("MIS_TAKEOFF_ALT", 1.0),
        "land_speed_m_s": ("MPC_LAND_SPEED", 1.0),
        "rtl_alt_m": ("RTL_RETURN_ALT", 1.0),
        "accept_radius_m": ("NAV_ACC_RAD", 1.0),
        "disarm_land_s": ("COM_DISARM_LAND", 1.0),
        "disarm_preflight_s": ("COM_DISARM_PRFLT", 1.0),
        "offboard_loss_s": ("COM_OF_LOSS_T", 1.0),
        "wind_speed_m_s": ("SIM_WIND_SPD", 1.0),
        "wind_from_deg": ("SIM_WIND_DIR", 1.0),
    }),
    # DO_SET_HOME 179, DO_DIGICAM_CONTROL 203 (camera trigger)
    accepted_commands=frozenset({179, 203}),
)

ARDUPILOT = Flavour(
    name="ardupilot",
    autopilot=3,
    streams_unrequested=False,
    param_bytewise=False,
    mission_item0_is_home=True,
    takeoff_param7_amsl=False,
    takeoff_needs_guided=True,
    unarmable_modes=frozenset({Mode.LAND, Mode.RTL}),
    modes=MappingProxyType(_ARDUPILOT_MODES),
    mode_aliases=MappingProxyType(_ARDUPILOT_ALIASES),
    params=_ARDUPILOT_PARAMS,
    initial_mode=Mode.MANUAL,
    flight_sw_version=(4 << 24) | (5 << 16) | (7 << 8) | 255,
    settings=MappingProxyType({
        "cruise_m_s": ("WPNAV_SPEED", 0.01),
        "max_speed_h_m_s": (None, 12.0),
        "max_speed_up_m_s": ("WPNAV_SPEED_UP", 0.01),
        "max_speed_down_m_s": ("WPNAV_SPEED_DN", 0.01),
        "max_accel_m_s2": ("WPNAV_ACCEL", 0.01),
        "takeoff_alt_m": (None, 2.5),
        "land_speed_m_s": ("LAND_SPEED", 0.01),
        "rtl_alt_m": ("RTL_ALT", 0.01),
        "accept_radius_m": ("WPNAV_RADIUS", 0.01),
        "disarm_land_s": (None, 1.0),
        "disarm_preflight_s": ("DISARM_DELAY", 1.0),
        "offboard_loss_s": (None, 3.0),
        "wind_speed_m_s": ("SIM_WIND_SPD", 1.0),
        "wind_from_deg": ("SIM_WIND_DIR", 1.0),
    }),
    # CONDITION_YAW 115, DO_SET_HOME 179, DO_SET_RELAY 181, DO_SET_SERVO 183,
    # DO_DIGICAM_CONTROL 203, DO_FENCE_ENABLE 207
    accepted_commands=frozenset({115, 179, 181, 183, 203, 207}),
)

FLAVOURS: MappingProxyType[str, Flavour] = MappingProxyType(
    {"px4": PX4, "ardupilot": ARDUPILOT}
)
