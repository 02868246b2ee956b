"""The simulated flight controller: modes, arming, takeoff/land/RTL, missions, guided setpoints.

Sans-I/O: it owns a :class:`~sitl.vehicle.physics.VehicleState`, is advanced with
``advance_to(now)`` (simulation seconds since boot) in fixed physics steps, takes commands as
method calls that return a :class:`CommandResult`, and reports what happened as events popped
with ``next_event()``. The MAVLink layer (:mod:`sitl.vehicle.core`) translates both ways.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import replace

from sitl.geo import GeoPoint
from sitl.vehicle.autopilot_events import (
    ACCEPTED,
    DENIED,
    FAILED,
    PREARM_FIRST_REPORT_S,
    SEV_INFO,
    TEMPORARILY_REJECTED,
    AutopilotEvent,
    CommandResult,
    CurrentItemChanged,
    FixAcquired,
    GuidedTarget,
    HomeChanged,
    ItemReached,
    ModeChanged,
    StatusText,
    Vec3,
)
from sitl.vehicle.flavour import Flavour, Mode
from sitl.vehicle.guidance import Guidance, wind_ned
from sitl.vehicle.mission import MissionItem
from sitl.vehicle.params import ParamTable
from sitl.vehicle.physics import Airframe, Setpoint, VehicleState

__all__ = [
    "AutopilotEvent",
    "CommandResult",
    "CurrentItemChanged",
    "FixAcquired",
    "FlightController",
    "GuidedTarget",
    "HomeChanged",
    "ItemReached",
    "ModeChanged",
    "StatusText",
    "wind_ned",
]

ARDUPILOT_GPS_FIX_SHARE = 0.2
"""ArduPilot: the GPS's own fix at this share of ``first_fix_s`` (when the EKF uses it);
ArduCopter 4.5 SITL: 8.7 s of 41.5 s."""


class FlightController(Guidance):
    """Modes and navigation of one simulated multicopter (see module docstring)."""

    def __init__(
        self,
        *,
        flavour: Flavour,
        params: ParamTable,
        home: GeoPoint,
        airframe: Airframe | None = None,
        dt_s: float = 0.02,
        gust_fraction: float = 0.2,
        first_fix_s: float = 0.0,
    ) -> None:
        if not 0.0 < dt_s <= 0.05:
            raise ValueError(f"dt_s must be in (0, 0.05], got {dt_s}")
        self.flavour = flavour
        self.params = params
        self.home = home
        self.dt_s = dt_s
        self.gust_fraction = gust_fraction
        self._base_airframe = airframe or Airframe()
        self.state = VehicleState(airframe=self._airframe())
        self.mode = flavour.initial_mode
        self._mode_after_disarm = flavour.initial_mode
        """PX4: the last mode that allows arming, which a disarm returns to (commander's
        ``UserModeIntention``: ``_nav_state_after_disarming``, not set by LAND or RTL)."""
        self.mission: list[MissionItem] = []
        self.mission_current = 0
        self.mission_finished = False
        self._events: deque[AutopilotEvent] = deque()
        self._hold_ned: Vec3 = (0.0, 0.0, 0.0)
        self._phase = ""
        self._target: Vec3 = (0.0, 0.0, 0.0)
        self._item_hold_until: float | None = None
        self._cruise_override_m_s: float | None = None
        self._guided: GuidedTarget | None = None
        self._landed_since: float | None = None
        self._armed_idle_since: float | None = None
        self._battery_warned = 0
        self._was_airborne = False
        self.roi_ned_m: Vec3 | None = None
        """Region of interest (DO_SET_ROI_*): the nose points at it while navigating."""
        self.first_fix_s = first_fix_s
        """Simulated seconds from boot to a GPS fix and estimator origin (0: at boot)."""
        self._fix_reported = first_fix_s <= 0.0
        self._next_prearm_report_s = PREARM_FIRST_REPORT_S
        self.home_ned_m: Vec3 = (0.0, 0.0, 0.0)
        """Home relative to the estimator origin (DO_SET_HOME moves it; RTL returns here)."""
        self.servo_pwm: list[int] = [0] * 16
        """PWM of SERVO1..16 as DO_SET_SERVO left them (motors 1-4 come from the state)."""
        self.relays: dict[int, bool] = {}
        self.camera_triggers = 0
        self._yaw_target_rad: float | None = None

    @property
    def has_fix(self) -> bool:
        """A 3D fix and an estimator origin: positions are valid, arming is possible."""
        return self.state.t_s >= self.first_fix_s - 1e-9

    @property
    def gps_has_fix(self) -> bool:
        """The GPS receiver's own 3D fix. ArduCopter's comes well before its EKF uses it
        (4.5 SITL, measured: fix 8.7 s, origin 18.5 s, EKF using GPS 41.5 s after start),
        and meanwhile it reports the GPS position in GLOBAL_POSITION_INT."""
        share = ARDUPILOT_GPS_FIX_SHARE if self.flavour.name == "ardupilot" else 1.0
        return self.state.t_s >= share * self.first_fix_s - 1e-9

    # ----------------------------------------------------------------- settings and events

    def setting(self, key: str) -> float:
        """A flavour-independent setting, read through this flavour's parameter and scale."""
        name, scale = self.flavour.settings[key]
        if name is None:
            return scale
        return self.params.get(name) * scale

    def on_params_changed(self) -> None:
        """Re-derive the airframe limits after a PARAM_SET."""
        self.state = replace(self.state, airframe=self._airframe())

    def _airframe(self) -> Airframe:
        return replace(
            self._base_airframe,
            max_speed_h_m_s=self.setting("max_speed_h_m_s"),
            max_speed_up_m_s=self.setting("max_speed_up_m_s"),
            max_speed_down_m_s=self.setting("max_speed_down_m_s"),
            max_accel_m_s2=self.setting("max_accel_m_s2"),
        )

    def next_event(self) -> AutopilotEvent | None:
        return self._events.popleft() if self._events else None

    def _text(self, severity: int, text: str) -> None:
        self._events.append(StatusText(severity=severity, text=text))

    def _set_mode(self, mode: Mode) -> None:
        changed = mode is not self.mode
        if changed:
            self.roi_ned_m = None
        self.mode = mode
        self._phase = ""
        if mode not in self.flavour.unarmable_modes:
            self._mode_after_disarm = mode
        if mode in (Mode.MANUAL, Mode.POSITION, Mode.HOLD):
            self._hold_ned = self._here_hold()
        if changed:
            self._events.append(ModeChanged(mode=mode))

    def _here_hold(self) -> Vec3:
        p = self.state.position_ned_m
        return (p[0], p[1], 0.0 if self.state.on_ground else p[2])

    @property
    def landed_state(self) -> int:
        """MAV_LANDED_STATE: 1 on ground, 2 in air, 3 taking off, 4 landing."""
        if self.state.on_ground:
            return 1
        if self.mode is Mode.TAKEOFF:
            return 3
        if self.mode is Mode.LAND or (self.mode is Mode.RTL and self._phase == "land") or (
            self.mode is Mode.MISSION and self._phase == "land"
        ):
            return 4
        return 2

    # ----------------------------------------------------------------------- commands

    def arm(self, *, force: bool = False) -> CommandResult:
        if self.state.armed:
            return CommandResult(result=ACCEPTED)
        if not force and not self.has_fix:
            return CommandResult(result=self._arm_refusal(), text=self._no_position_text())
        if not force and self.mode in self.flavour.unarmable_modes:
            return CommandResult(result=self._arm_refusal(),
                                 text=f"Arm: Mode not armable ({self.mode.value})")
        if not force and self.state.battery_remaining < 0.1:
            return CommandResult(result=self._arm_refusal(), text="Arm: Battery too low")
        self.state = replace(self.state, armed=True)
        self._armed_idle_since = self.state.t_s
        self._landed_since = None
        self._text(SEV_INFO, "Armed by external command")
        return CommandResult(result=ACCEPTED)

    def disarm(self, *, force: bool = False) -> CommandResult:
        if not self.state.armed:
            return CommandResult(result=ACCEPTED)
        if not force and not self.state.on_ground:
            return CommandResult(result=self._arm_refusal(), text="Disarm: not landed")
        self._disarm("Disarmed by external command")
        return CommandResult(result=ACCEPTED)

    def _no_position_text(self, prefix: str = "Arm") -> str:
        """What the real stacks say when asked to arm before the estimator has a position.

        ArduPilot prefixes the checks it runs on an arm command with "Arm:" and the ones it
        reports every 30 s while disarmed with "PreArm:"."""
        if self.flavour.name == "px4":
            return "Navigation error: No valid global position estimate"
        if self.mode in (Mode.MANUAL,):
            return f"{prefix}: AHRS: waiting for home"
        return f"{prefix}: Need Position Estimate"

    def _arm_refusal(self) -> int:
        """PX4's commander answers a denied arming transition TEMPORARILY_REJECTED."""
        return FAILED if self.flavour.name == "ardupilot" else TEMPORARILY_REJECTED

    def _refusal(self) -> int:
        return FAILED if self.flavour.name == "ardupilot" else DENIED

    def _disarm(self, text: str) -> None:
        self.state = replace(self.state, armed=False, setpoint=Setpoint())
        self._was_airborne = False
        self._armed_idle_since = None
        self._landed_since = None
        self._text(SEV_INFO, text)
        if self.flavour.name == "px4" and self.mode is not self._mode_after_disarm:
            # PX4 SIH, landed in LAND after MISSION: disarmed in MISSION (measured)
            self._set_mode(self._mode_after_disarm)

    def set_mode(self, mode: Mode) -> CommandResult:
        if mode is Mode.GUIDED and self.flavour.name == "px4":
            g = self._guided
            if g is None or self.state.t_s - g.t_s > 0.5:
                return CommandResult(result=DENIED, text="Offboard: no setpoint stream")
        if mode is Mode.TAKEOFF:
            return self.takeoff(None)
        if mode is Mode.MISSION:
            return self.start_mission(None)
        if mode is Mode.GUIDED and self.flavour.name == "ardupilot":
            self._guided = GuidedTarget(position_ned_m=self._here_hold(), t_s=self.state.t_s)
        self._set_mode(mode)
        if mode is Mode.RTL:
            self._phase = "climb"
        return CommandResult(result=ACCEPTED)

    def takeoff(self, alt_rel_m: float | None) -> CommandResult:
        """Climb vertically to ``alt_rel_m`` above home (None: the takeoff-altitude setting)."""
        px4 = self.flavour.name == "px4"
        if not self.has_fix:
            if px4:  # the switch to Takeoff needs a global position
                return CommandResult(result=TEMPORARILY_REJECTED,
                                     text="Takeoff denied! Please disarm and retry")
            return CommandResult(result=FAILED, text=self._no_position_text())
        if not self.state.armed and not px4:
            # PX4 takes NAV_TAKEOFF while disarmed: it switches to Takeoff and climbs once armed.
            return CommandResult(result=self._refusal(), text="Takeoff: not armed")
        if self.flavour.takeoff_needs_guided and self.mode is not Mode.GUIDED:
            return CommandResult(result=FAILED, text="Takeoff: mode must be GUIDED")
        if not self.state.on_ground and self.flavour.takeoff_needs_guided:
            return CommandResult(result=FAILED, text="Takeoff: already flying")
        alt = self.setting("takeoff_alt_m") if alt_rel_m is None or not math.isfinite(
            alt_rel_m) else alt_rel_m
        alt = self._min_takeoff_alt(alt)
        p = self.state.position_ned_m
        self._target = (p[0], p[1], -alt)
        self._set_mode(Mode.TAKEOFF)
        self._text(SEV_INFO, f"Takeoff to {alt:.1f} m")
        return CommandResult(result=ACCEPTED)

    def _min_takeoff_alt(self, alt: float) -> float:
        """PX4 climbs at least MIS_TAKEOFF_ALT (and says so); ArduPilot at least 1 m."""
        if self.flavour.name != "px4":
            return max(alt, 1.0)
        floor = self.setting("takeoff_alt_m")
        if alt < floor:
            self._text(SEV_INFO, f"Using minimum takeoff altitude: {floor:.2f} m")
            return floor
        return alt

    def land(self) -> CommandResult:
        self._set_mode(Mode.LAND)
        p = self.state.position_ned_m
        self._target = (p[0], p[1], 0.0)
        return CommandResult(result=ACCEPTED)

    def return_to_launch(self) -> CommandResult:
        return self.set_mode(Mode.RTL)

    def start_mission(self, first_seq: int | None) -> CommandResult:
        """Enter AUTO/MISSION at ``first_seq`` (None: the current item)."""
        if not self.mission:
            return CommandResult(result=FAILED if self.flavour.name == "ardupilot" else DENIED,
                                 text="Mission: no mission loaded")
        seq = self.mission_current if first_seq is None else first_seq
        if self.mission_finished and first_seq is None:
            seq = self._first_seq()
        seq = min(max(seq, self._first_seq()), len(self.mission) - 1)
        self._set_mode(Mode.MISSION)
        self.mission_finished = False
        self._begin_item(seq)
        return CommandResult(result=ACCEPTED)

    def _first_seq(self) -> int:
        return 1 if self.flavour.mission_item0_is_home and len(self.mission) > 1 else 0

    def set_mission(self, items: list[MissionItem]) -> None:
        """A new mission replaces the old; a flying mission restarts at its first item."""
        self.mission = list(items)
        self.mission_finished = False
        first = self._first_seq()
        self.mission_current = first
        self._events.append(CurrentItemChanged(seq=first))
        if self.mode is Mode.MISSION:
            if items:
                self._begin_item(first)
            else:
                self._set_mode(Mode.HOLD)

    def set_current_item(self, seq: int) -> CommandResult:
        if not 0 <= seq < max(len(self.mission), 1):
            return CommandResult(result=DENIED, text=f"Mission: no item {seq}")
        if self.mode is Mode.MISSION and self.mission:
            self.mission_finished = False
            self._begin_item(seq)
        else:
            self.mission_current = seq
            self._events.append(CurrentItemChanged(seq=seq))
        return CommandResult(result=ACCEPTED)

    def set_speed(self, speed_m_s: float) -> CommandResult:
        if speed_m_s > 0.0:
            self._cruise_override_m_s = speed_m_s
        return CommandResult(result=ACCEPTED)

    def set_roi(self, roi_ned_m: Vec3 | None) -> CommandResult:
        """DO_SET_ROI_LOCATION / DO_SET_ROI_NONE sent as a command."""
        self.roi_ned_m = roi_ned_m
        return CommandResult(result=ACCEPTED)

    def set_guided_target(self, target: GuidedTarget) -> None:
        """Store an offboard/guided setpoint (followed only in GUIDED mode)."""
        self._guided = target

    def reposition(self, target_ned_m: Vec3) -> CommandResult:
        """DO_REPOSITION: fly to a point and hold there (PX4 Hold, ArduPilot Guided)."""
        if not self.state.armed or self.state.on_ground:
            return CommandResult(result=self._refusal(), text="Reposition: not flying")
        if self.flavour.name == "ardupilot":
            self._set_mode(Mode.GUIDED)
            self._guided = GuidedTarget(position_ned_m=target_ned_m, t_s=self.state.t_s)
        else:
            self._set_mode(Mode.HOLD)
            self._hold_ned = target_ned_m
        return CommandResult(result=ACCEPTED)

    def set_servo(self, channel: int, pwm: int) -> CommandResult:
        """DO_SET_SERVO: ArduCopter drives only channels no function owns (not the motors)."""
        if not 1 <= channel <= 16:
            return CommandResult(result=FAILED)
        if channel <= 4:
            return CommandResult(result=FAILED,
                                 text=f"ServoRelayEvent: Channel {channel} is already in use")
        self.servo_pwm[channel - 1] = pwm
        return CommandResult(result=ACCEPTED)

    def set_relay(self, instance: int, on: bool) -> CommandResult:
        """DO_SET_RELAY: only a relay with a function (RELAYn_FUNCTION > 0) switches."""
        name = f"RELAY{instance + 1}_FUNCTION"
        if instance < 0 or name not in self.params or self.params.get(name) <= 0:
            return CommandResult(result=FAILED)
        self.relays[instance] = on
        return CommandResult(result=ACCEPTED)

    def trigger_camera(self) -> CommandResult:
        self.camera_triggers += 1
        return CommandResult(result=ACCEPTED)

    def condition_yaw(self, angle_deg: float, direction: float, relative: bool) -> CommandResult:
        """CONDITION_YAW as ArduCopter: 0..360 deg, absolute or relative; flown in GUIDED and
        AUTO (the other modes ignore it, but the command is still accepted)."""
        if not (math.isfinite(angle_deg) and 0.0 <= angle_deg <= 360.0):
            return CommandResult(result=FAILED)
        if relative:
            sign = -1.0 if direction < 0 else 1.0
            yaw = self.state.yaw_rad + sign * math.radians(angle_deg)
        else:
            yaw = math.radians(angle_deg)
        self._yaw_target_rad = math.atan2(math.sin(yaw), math.cos(yaw))
        if self.mode is Mode.GUIDED and self._guided is not None:
            self._guided = replace(self._guided, yaw_rad=self._yaw_target_rad)
        return CommandResult(result=ACCEPTED)

    def set_home(self, home_ned_m: Vec3 | None) -> CommandResult:
        """DO_SET_HOME (None: here). Refused until the estimator has an origin."""
        if not self.has_fix:
            return CommandResult(result=FAILED)
        p = self.state.position_ned_m
        self.home_ned_m = (p[0], p[1], p[2]) if home_ned_m is None else home_ned_m
        self._events.append(HomeChanged())
        return CommandResult(result=ACCEPTED)
