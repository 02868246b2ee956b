"""Guidance of the simulated flight controller (a mixin): physics steps, setpoints per mode,
mission progress, landing detection and the battery failsafe.

:class:`Guidance` is the simulation half of :class:`~sitl.vehicle.autopilot.FlightController`;
the command half (arming, modes, takeoff, mission upload) stays there.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import replace
from typing import TYPE_CHECKING

from sitl.geo import GeoPoint
from sitl.vehicle.autopilot_events import (
    PREARM_REPORT_PERIOD_S,
    SEV_CRITICAL,
    SEV_INFO,
    SEV_WARNING,
    AutopilotEvent,
    CommandResult,
    CurrentItemChanged,
    FixAcquired,
    GuidedTarget,
    ItemReached,
    Vec3,
)
from sitl.vehicle.flavour import Flavour, Mode
from sitl.vehicle.mission import (
    CMD_CHANGE_SPEED,
    CMD_LAND,
    CMD_LOITER_TIME,
    CMD_LOITER_UNLIM,
    CMD_RTL,
    CMD_SET_ROI,
    CMD_SET_ROI_LOCATION,
    CMD_SET_ROI_NONE,
    CMD_TAKEOFF,
    CMD_WAYPOINT,
    MissionItem,
    is_nav_command,
)
from sitl.vehicle.physics import Setpoint, VehicleState, step


def wind_ned(t_s: float, speed_m_s: float, from_deg: float, gust_fraction: float) -> Vec3:
    """Wind velocity (NED, m/s) blowing *from* ``from_deg``, with deterministic gusts.

    Gusts are a sum of incommensurate sines, so runs are reproducible without an RNG.
    """
    if speed_m_s <= 0.0:
        return (0.0, 0.0, 0.0)
    gust = 1.0 + gust_fraction * (0.6 * math.sin(0.31 * t_s) + 0.4 * math.sin(1.07 * t_s + 1.3))
    turn = math.radians(8.0) * gust_fraction * math.sin(0.13 * t_s)
    to_rad = math.radians(from_deg) + math.pi + turn
    s = speed_m_s * gust
    return (s * math.cos(to_rad), s * math.sin(to_rad), 0.0)


class Guidance:
    """Advance the vehicle in fixed physics steps; mixed into FlightController."""

    # State that FlightController.__init__ sets; declared here so the mixin type-checks.
    flavour: Flavour
    home: GeoPoint
    dt_s: float
    gust_fraction: float
    state: VehicleState
    mode: Mode
    mission: list[MissionItem]
    mission_current: int
    mission_finished: bool
    home_ned_m: Vec3
    roi_ned_m: Vec3 | None
    _events: deque[AutopilotEvent]
    _hold_ned: Vec3
    _phase: str
    _target: Vec3
    _item_hold_until: float | None
    _cruise_override_m_s: float | None
    _guided: GuidedTarget | None
    _landed_since: float | None
    _armed_idle_since: float | None
    _battery_warned: int
    _was_airborne: bool
    _fix_reported: bool
    _next_prearm_report_s: float

    if TYPE_CHECKING:  # provided by FlightController
        @property
        def has_fix(self) -> bool:
            raise NotImplementedError

        def setting(self, key: str) -> float:
            raise NotImplementedError

        def _text(self, severity: int, text: str) -> None:
            raise NotImplementedError

        def _set_mode(self, mode: Mode) -> None:
            raise NotImplementedError

        def _here_hold(self) -> Vec3:
            raise NotImplementedError

        def _min_takeoff_alt(self, alt: float) -> float:
            raise NotImplementedError

        def _no_position_text(self, prefix: str = "Arm") -> str:
            raise NotImplementedError

        def _disarm(self, text: str) -> None:
            raise NotImplementedError

        def set_mode(self, mode: Mode) -> CommandResult:
            raise NotImplementedError

        def set_speed(self, speed_m_s: float) -> CommandResult:
            raise NotImplementedError

        def land(self) -> CommandResult:
            raise NotImplementedError

    def advance_to(self, now: float) -> None:
        """Run fixed physics steps until the simulated time reaches ``now``."""
        while self.state.t_s + self.dt_s <= now + 1e-9:
            self._tick()

    def _tick(self) -> None:
        t = self.state.t_s
        wind = wind_ned(t, self.setting("wind_speed_m_s"), self.setting("wind_from_deg"),
                        self.gust_fraction)
        self.state = replace(self.state, setpoint=self._setpoint(), wind_ned_m_s=wind)
        self.state = step(self.state, self.dt_s)
        self._after_step()

    def _cruise(self) -> float:
        return self._cruise_override_m_s or self.setting("cruise_m_s")

    def _goto(self, target: Vec3, *, speed: float | None = None,
              yaw_rad: float | None = None) -> Setpoint:
        """Fly to target; from the ground climb vertically first (as autopilots do).

        The nose points at the region of interest if one is set, else at ``yaw_rad``
        (NAV_WAYPOINT param4, PX4 only), else along the flight.
        """
        p = self.state.position_ned_m
        if self.roi_ned_m is not None:
            dn, de = self.roi_ned_m[0] - p[0], self.roi_ned_m[1] - p[1]
            yaw_rad = math.atan2(de, dn) if math.hypot(dn, de) > 1.0 else self.state.yaw_rad
        if -p[2] < min(-target[2], 2.0) - 0.3 and math.hypot(target[0] - p[0],
                                                            target[1] - p[1]) > 1.0:
            return Setpoint(position_ned_m=(p[0], p[1], target[2]))
        return Setpoint(position_ned_m=target, speed_m_s=speed or self._cruise(),
                        yaw_rad=yaw_rad, yaw_to_travel=yaw_rad is None)

    def _descend(self, target_ne: tuple[float, float]) -> Setpoint:
        p = self.state.position_ned_m
        speed = self.setting("land_speed_m_s")
        if -p[2] > 10.0:
            speed = self.state.airframe.max_speed_down_m_s
        k = self.state.airframe.position_gain_1_s
        return Setpoint(velocity_ned_m_s=(k * (target_ne[0] - p[0]), k * (target_ne[1] - p[1]),
                                          speed))

    def _setpoint(self) -> Setpoint:
        mode = self.mode
        if not self.state.armed:
            return Setpoint()
        if mode in (Mode.MANUAL, Mode.POSITION, Mode.HOLD):
            return Setpoint(position_ned_m=self._hold_ned)
        if mode is Mode.TAKEOFF:
            return Setpoint(position_ned_m=self._target)
        if mode is Mode.LAND:
            return self._descend((self._target[0], self._target[1]))
        if mode is Mode.RTL:
            return self._rtl_setpoint()
        if mode is Mode.MISSION:
            return self._mission_setpoint()
        if mode is Mode.GUIDED:
            return self._guided_setpoint()
        raise AssertionError(f"unhandled mode {mode}")

    def _rtl_setpoint(self) -> Setpoint:
        p = self.state.position_ned_m
        rtl_alt = max(self.setting("rtl_alt_m"), -p[2])
        if self._phase in ("", "climb"):
            self._phase = "climb"
            self._target = (p[0], p[1], -rtl_alt)
            return Setpoint(position_ned_m=(p[0], p[1], -rtl_alt))
        if self._phase == "return":
            return Setpoint(position_ned_m=self._target, speed_m_s=self._cruise(),
                            yaw_to_travel=True)
        return self._descend((self.home_ned_m[0], self.home_ned_m[1]))

    def _guided_setpoint(self) -> Setpoint:
        g = self._guided
        if g is None:
            return Setpoint(position_ned_m=self._here_hold())
        if g.position_ned_m is not None:
            return Setpoint(position_ned_m=g.position_ned_m, yaw_rad=g.yaw_rad,
                            yaw_to_travel=g.yaw_rad is None)
        if g.velocity_ned_m_s is not None:
            if self.state.t_s - g.t_s > self.setting("offboard_loss_s"):
                if self.flavour.name == "px4":
                    self._text(SEV_WARNING, "Failsafe: offboard setpoints lost, holding")
                    self._set_mode(Mode.HOLD)
                    return Setpoint(position_ned_m=self._hold_ned)
                self._guided = GuidedTarget(position_ned_m=self._here_hold(), t_s=self.state.t_s)
                return Setpoint(position_ned_m=self._guided.position_ned_m)
            return Setpoint(velocity_ned_m_s=g.velocity_ned_m_s, yaw_rad=g.yaw_rad)
        return Setpoint(position_ned_m=self._here_hold(), yaw_rad=g.yaw_rad)

    # ---------------------------------------------------------------------- missions

    def _begin_item(self, seq: int) -> None:
        self.mission_current = seq
        self._events.append(CurrentItemChanged(seq=seq))
        self._item_hold_until = None
        self._phase = ""
        item = self.mission[seq]
        here = self.state.position_ned_m
        if item.command == CMD_TAKEOFF:
            alt = item.alt_rel_m(self.home)
            self._target = (here[0], here[1], -self._min_takeoff_alt(alt))
        elif item.command == CMD_LAND:
            t = item.target_ned_m(self.home, here)
            self._target = (t[0], t[1], here[2])
            self._phase = "approach" if item.has_position else "land"
        elif item.command in (CMD_WAYPOINT, CMD_LOITER_TIME, CMD_LOITER_UNLIM):
            self._target = item.target_ned_m(self.home, here)
        elif item.command == CMD_RTL:
            self._phase = "climb"
        elif item.command == CMD_CHANGE_SPEED:
            self.set_speed(item.param2)
        elif item.command == CMD_SET_ROI_LOCATION or (
                item.command == CMD_SET_ROI and item.param1 == 3):
            self.roi_ned_m = item.target_ned_m(self.home, here)
        elif item.command == CMD_SET_ROI_NONE or (item.command == CMD_SET_ROI
                                                  and item.param1 == 0):
            self.roi_ned_m = None

    def _mission_setpoint(self) -> Setpoint:
        if self.mission_finished or not self.mission:
            return Setpoint(position_ned_m=self._hold_ned)
        item = self.mission[self.mission_current]
        if item.command == CMD_TAKEOFF:
            return Setpoint(position_ned_m=self._target)
        if item.command == CMD_LAND:
            if self._phase == "approach":
                return self._goto(self._target)
            return self._descend((self._target[0], self._target[1]))
        if item.command == CMD_RTL:
            return self._rtl_setpoint()
        if item.command in (CMD_WAYPOINT, CMD_LOITER_TIME, CMD_LOITER_UNLIM):
            yaw = item.param4 if item.command == CMD_WAYPOINT and self.flavour.name == "px4" \
                else math.nan
            return self._goto(self._target,
                              yaw_rad=math.radians(yaw) if math.isfinite(yaw) else None)
        return Setpoint(position_ned_m=self._here_hold())

    def _dist(self, target: Vec3) -> tuple[float, float]:
        p = self.state.position_ned_m
        return math.hypot(target[0] - p[0], target[1] - p[1]), abs(target[2] - p[2])

    def _mission_progress(self) -> None:
        if self.mission_finished or not self.mission or not self.state.armed:
            return
        item = self.mission[self.mission_current]
        cmd = item.command
        done = False
        if cmd == CMD_TAKEOFF:
            done = self._dist(self._target)[1] < 0.5
        elif cmd in (CMD_WAYPOINT, CMD_LOITER_TIME, CMD_LOITER_UNLIM):
            radius = item.param2 if cmd == CMD_WAYPOINT and item.param2 > 0 else self.setting(
                "accept_radius_m")
            dh, dv = self._dist(self._target)
            if dh < radius and dv < max(1.0, radius / 2):
                hold_s = item.param1 if cmd in (CMD_WAYPOINT, CMD_LOITER_TIME) else math.inf
                if math.isnan(hold_s) or hold_s < 0.0:
                    hold_s = 0.0
                if self._item_hold_until is None:
                    self._item_hold_until = self.state.t_s + hold_s
                    if cmd == CMD_LOITER_UNLIM:
                        self._events.append(ItemReached(seq=self.mission_current))
                        self._hold_ned = self._target
                done = self.state.t_s >= self._item_hold_until
        elif cmd == CMD_LAND:
            if self._phase == "approach" and self._dist(self._target)[0] < 1.0:
                self._phase = "land"
            done = self._phase == "land" and self.state.on_ground
        elif cmd == CMD_RTL:
            done = self.state.on_ground and self._phase == "land"
        else:
            done = True  # DO_/CONDITION_ items act at once (or are ignored)
        if not done:
            return
        if is_nav_command(cmd) and cmd != CMD_LOITER_UNLIM:
            self._events.append(ItemReached(seq=self.mission_current))
        nxt = self.mission_current + 1
        if nxt < len(self.mission) and item.autocontinue:
            self._begin_item(nxt)
            return
        self.mission_finished = True
        self._hold_ned = self._here_hold()
        self._text(SEV_INFO, "Mission finished" if nxt >= len(self.mission) else
                   f"Mission paused at item {self.mission_current}")
        if self.flavour.name == "px4" and self.state.armed:
            self._set_mode(Mode.HOLD)

    def _after_step(self) -> None:
        st = self.state
        t = st.t_s
        if not self._fix_reported and self.has_fix:
            self._fix_reported = True
            self._events.append(FixAcquired())
        elif (not self._fix_reported and not st.armed and self.flavour.name == "ardupilot"
              and t >= self._next_prearm_report_s):
            self._next_prearm_report_s = t + PREARM_REPORT_PERIOD_S
            self._text(SEV_CRITICAL, self._no_position_text("PreArm"))
        if self.mode is Mode.TAKEOFF and self._dist(self._target)[1] < 0.3:
            if self.flavour.name == "ardupilot":
                self._set_mode(Mode.GUIDED)
                self._guided = GuidedTarget(position_ned_m=self._target, t_s=t)
            else:
                self._set_mode(Mode.HOLD)
                self._hold_ned = self._target
        elif self.mode is Mode.RTL or (self.mode is Mode.MISSION and self.mission
                                       and not self.mission_finished
                                       and self.mission[self.mission_current].command == CMD_RTL):
            if self._phase == "climb" and self._dist(self._target)[1] < 0.5:
                self._phase = "return"
                self._target = (self.home_ned_m[0], self.home_ned_m[1], self._target[2])
            elif self._phase == "return" and self._dist(self._target)[0] < 1.0:
                self._phase = "land"
        if self.mode is Mode.MISSION:
            self._mission_progress()
        self._battery_failsafe()
        if not st.armed:
            return
        # Auto-disarm: shortly after touchdown, or when armed on the ground and idle too long.
        if not st.on_ground:
            self._was_airborne = True
            self._landed_since = None
            self._armed_idle_since = None
            return
        if not self._setpoint_is_ground():
            self._armed_idle_since = None
            return
        if self._was_airborne:
            if self._landed_since is None:
                self._landed_since = t
                self._text(SEV_INFO, "Landing detected")
            elif t - self._landed_since >= self.setting("disarm_land_s"):
                self._disarm("Disarmed by landing")
            return
        if self._armed_idle_since is None:
            self._armed_idle_since = t
        limit = self.setting("disarm_preflight_s")
        if limit > 0 and t - self._armed_idle_since >= limit:
            self._disarm("Disarmed by auto preflight disarming")

    def _setpoint_is_ground(self) -> bool:
        sp = self.state.setpoint
        if sp.position_ned_m is not None:
            return sp.position_ned_m[2] >= -0.05
        if sp.velocity_ned_m_s is not None:
            return sp.velocity_ned_m_s[2] >= 0.0
        return True

    def _battery_failsafe(self) -> None:
        level = self.state.battery_remaining
        flying = self.state.armed and not self.state.on_ground
        if level < 0.15 and self._battery_warned == 0:
            self._battery_warned = 1
            self._text(SEV_WARNING, "Low battery: return advised")
        if level < 0.07 and self._battery_warned == 1 and flying:
            self._battery_warned = 2
            self._text(SEV_CRITICAL, "Critical battery: returning to launch")
            self.set_mode(Mode.RTL)
        if level < 0.03 and self._battery_warned == 2 and flying:
            self._battery_warned = 3
            self._text(SEV_CRITICAL, "Emergency battery: landing")
            self.land()
