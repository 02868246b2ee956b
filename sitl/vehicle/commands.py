"""Commands, modes, parameters and guided targets of the simulated vehicle (a mixin).

:class:`CommandHandlers` is the part of :class:`~sitl.vehicle.core.VehicleCore` that answers
COMMAND_LONG/INT, SET_MODE, PARAM_* and SET_POSITION_TARGET_*; it uses the core's ``fc``,
``params``, ``flavour``, ``_send`` and ``statustext``.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sitl.vehicle.autopilot import FlightController
from sitl.vehicle.autopilot_events import (
    ACCEPTED,
    DENIED,
    FAILED,
    TEMPORARILY_REJECTED,
    UNSUPPORTED,
    CommandResult,
    GuidedTarget,
)
from sitl.vehicle.fields import finite_field, int_field, lat_lon_field, text_field
from sitl.vehicle.flavour import Flavour, decode_param_value, encode_param_value
from sitl.vehicle.mission import commanded_alt_rel_m
from sitl.vehicle.params import ParamTable
from sitl.vehicle.stream_tables import (
    DEFAULT_INTERVALS_S,
    MSG_HEARTBEAT,
    PX4_EXTRA_INTERVALS_S,
)
from sitl.vehicle.telemetry import Telemetry

if TYPE_CHECKING:
    from sitl.vehicle.core import VehicleConfig


class CommandHandlers:
    """COMMAND_*, SET_MODE, PARAM_* and guided targets; mixed into VehicleCore."""

    config: VehicleConfig
    fc: FlightController
    flavour: Flavour
    params: ParamTable
    counters: Counter[str]
    telemetry: Telemetry
    _reboot_requested: bool
    _builders: Mapping[int, Callable[[float], Any]]  # pymavlink messages are untyped

    if TYPE_CHECKING:  # provided by VehicleCore
        def _send(self, msg: Any) -> None:
            raise NotImplementedError

        def statustext(self, severity: int, text: str) -> None:
            raise NotImplementedError

        def set_interval(self, msg_id: int, interval_s: float | None, now: float) -> bool:
            raise NotImplementedError

        def interval_of(self, msg_id: int) -> float | None:
            raise NotImplementedError

        def _geo_to_ned(self, lat_deg: float, lon_deg: float, alt_rel_m: float
                        ) -> tuple[float, float, float]:
            raise NotImplementedError

    def _ack(self, msg: Any, command: int, res: CommandResult) -> None:
        if res.text:
            self.statustext(4 if not res.ok else 6, res.text)
        self._send(mavlink.MAVLink_command_ack_message(
            command, res.result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()))

    def _on_command_long(self, msg: Any, now: float) -> None:
        params = [msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6,
                  msg.param7]
        self._command(msg, msg.command, params, frame=None, now=now)

    def _on_command_int(self, msg: Any, now: float) -> None:
        params = [msg.param1, msg.param2, msg.param3, msg.param4, msg.x / 1e7, msg.y / 1e7,
                  msg.z]
        self._command(msg, msg.command, params, frame=msg.frame, now=now)

    def _command(self, msg: Any, command: int, p: list[float], *, frame: int | None,
                 now: float) -> None:
        fc = self.fc
        follow_up: Any = None
        res: CommandResult
        if command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            force = abs(p[1] - 21196.0) < 0.5
            res = fc.arm(force=force) if p[0] >= 0.5 else fc.disarm(force=force)
        elif command == mavlink.MAV_CMD_NAV_TAKEOFF:
            alt: float | None = p[6] if math.isfinite(p[6]) else None
            if alt is not None and self.flavour.takeoff_param7_amsl:
                alt = commanded_alt_rel_m(frame, alt, self.config.home)
            res = fc.takeoff(alt)
        elif command == mavlink.MAV_CMD_NAV_LAND:
            res = fc.land()
        elif command == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            res = fc.return_to_launch()
        elif command == mavlink.MAV_CMD_DO_SET_MODE:
            res = self._set_mode_from(int_field(p[0], "base_mode"), int_field(p[1], "custom_mode"),
                                      int_field(p[2], "custom_sub_mode") if math.isfinite(p[2])
                                      else 0)
        elif command == mavlink.MAV_CMD_MISSION_START:
            res = fc.start_mission(int_field(p[0], "first_item") if p[0] > 0 else None)
        elif command == mavlink.MAV_CMD_DO_SET_MISSION_CURRENT:
            res = fc.set_current_item(int_field(p[0], "seq"))
        elif command == mavlink.MAV_CMD_DO_CHANGE_SPEED:
            res = fc.set_speed(p[1])
        elif command == mavlink.MAV_CMD_DO_REPOSITION:
            here = fc.state.position_ned_m
            if math.isfinite(p[4]) and math.isfinite(p[5]):
                lat_lon_field(p[4], p[5])
                alt_rel = -here[2]
                if math.isfinite(p[6]):
                    alt_rel = commanded_alt_rel_m(frame, p[6], self.config.home)
                target = self._geo_to_ned(p[4], p[5], alt_rel)
            else:
                target = here
            res = fc.reposition(target)
        elif command == mavlink.MAV_CMD_DO_SET_ROI_LOCATION:
            lat, lon = lat_lon_field(p[4], p[5])
            alt_rel = 0.0
            if math.isfinite(p[6]):
                alt_rel = commanded_alt_rel_m(frame, p[6], self.config.home)
            res = fc.set_roi(self._geo_to_ned(lat, lon, alt_rel))
        elif command == mavlink.MAV_CMD_DO_SET_ROI_NONE:
            res = fc.set_roi(None)
        elif command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            msg_id, interval_us = int_field(p[0], "message_id"), int_field(p[1], "interval_us")
            if interval_us < 0:
                interval: float | None = None
            elif interval_us == 0:
                interval = {**DEFAULT_INTERVALS_S, **PX4_EXTRA_INTERVALS_S}.get(msg_id, 1.0)
            elif self.flavour.name == "ardupilot":  # whole milliseconds; 0 ms stops it
                interval = interval_us // 1000 / 1e3 or None
            else:
                interval = interval_us / 1e6
            if interval is not None and interval < self.flavour.min_stream_interval_s \
                    and self.flavour.name == "ardupilot":
                res = CommandResult(result=TEMPORARILY_REJECTED)  # its cap_message_interval
            elif msg_id == MSG_HEARTBEAT and self.flavour.name == "px4":
                res = CommandResult(result=FAILED)  # PX4 SIH: its rate is not settable
            else:
                ok = self.set_interval(msg_id, interval, now)
                # A message the stack lacks: ArduCopter 4.5 DENIED with a STATUSTEXT, PX4 SIH
                # FAILED and nothing else (both measured, docs/sitl.md).
                res = CommandResult(result=ACCEPTED if ok else FAILED)
                if not ok and self.flavour.name == "ardupilot":
                    self.statustext(6, f"No ap_message for mavlink id ({msg_id})")
                    res = CommandResult(result=DENIED)
        elif command == mavlink.MAV_CMD_GET_MESSAGE_INTERVAL:
            msg_id = int_field(p[0], "message_id")
            if msg_id in self._builders:
                iv = self.interval_of(msg_id)
                follow_up = mavlink.MAVLink_message_interval_message(
                    msg_id, -1 if iv is None else int(iv * 1e6))
                res = CommandResult(result=ACCEPTED)
            elif self.flavour.name == "px4":  # PX4 SIH: interval 0, "not available"
                follow_up = mavlink.MAVLink_message_interval_message(msg_id, 0)
                res = CommandResult(result=ACCEPTED)
            else:
                res = CommandResult(result=UNSUPPORTED)
        elif command == mavlink.MAV_CMD_REQUEST_MESSAGE:
            builder = self._builders.get(int_field(p[0], "message_id"))
            follow_up = builder(now) if builder else None
            missing = DENIED if self.flavour.name == "px4" else UNSUPPORTED  # PX4 SIH: DENIED
            res = CommandResult(result=missing if builder is None else
                                FAILED if follow_up is None else ACCEPTED)
        elif command == mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            res = CommandResult(result=ACCEPTED)
            follow_up = self.telemetry.autopilot_version(now)
        elif command == mavlink.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN:
            res = self._reboot(p[0])
        elif command == mavlink.MAV_CMD_GET_HOME_POSITION:
            follow_up = self.telemetry.home_position(now)
            res = CommandResult(result=FAILED if follow_up is None else ACCEPTED)
        elif command in self.flavour.accepted_commands:
            res = self._peripheral_command(command, p, frame)
        else:
            self.counters["unsupported_command"] += 1
            res = CommandResult(result=UNSUPPORTED)
        self._ack(msg, command, res)
        if follow_up is not None:
            self._send(follow_up)

    def _reboot(self, action: float) -> CommandResult:
        """param1 1 (reboot) or 3 (to the bootloader: here a reboot too) when disarmed: ACK
        ACCEPTED, then silent for ``reboot_s`` and a fresh boot (the core). ArduPilot's
        handle_preflight_reboot answers FAILED while armed and UNSUPPORTED for other param1;
        PX4's Commander accepts 0 (nothing to do) and DENIES the rest."""
        ardupilot = self.flavour.name == "ardupilot"
        if not ardupilot and action == 0.0:
            return CommandResult(result=ACCEPTED)
        if self.fc.state.armed:
            return CommandResult(result=FAILED if ardupilot else DENIED)
        if action not in (1.0, 3.0):
            return CommandResult(result=UNSUPPORTED if ardupilot else DENIED)
        self._reboot_requested = True
        return CommandResult(result=ACCEPTED)

    def _peripheral_command(self, command: int, p: list[float], frame: int | None
                            ) -> CommandResult:
        """Servo, relay, yaw, home, camera and fence commands (``Flavour.accepted_commands``)."""
        fc = self.fc
        if command == mavlink.MAV_CMD_DO_SET_SERVO:
            return fc.set_servo(int_field(p[0], "instance"), int_field(p[1], "pwm"))
        if command == mavlink.MAV_CMD_DO_SET_RELAY:
            return fc.set_relay(int_field(p[0], "instance"), p[1] >= 0.5)
        if command == mavlink.MAV_CMD_CONDITION_YAW:
            if not math.isfinite(p[3]) or p[3] not in (0.0, 1.0):
                return CommandResult(result=FAILED)
            return fc.condition_yaw(p[0], p[2], relative=p[3] == 1.0)
        if command == mavlink.MAV_CMD_DO_SET_HOME:
            # param1 = 1, or lat/lon both 0: here (as ArduPilot reads it).
            if p[0] >= 0.5 or (p[4] == 0.0 and p[5] == 0.0):
                return fc.set_home(None)
            lat, lon = lat_lon_field(p[4], p[5])
            alt_amsl = p[6] if math.isfinite(p[6]) else self.config.home.alt_m
            return fc.set_home(self._geo_to_ned(lat, lon, alt_amsl - self.config.home.alt_m))
        if command == mavlink.MAV_CMD_DO_DIGICAM_CONTROL:
            return fc.trigger_camera()
        if command == mavlink.MAV_CMD_DO_FENCE_ENABLE:
            action = int_field(p[0], "enable")
            if action not in (0, 1, 2):
                return CommandResult(result=FAILED)
            self.params.set("FENCE_ENABLE", 1.0 if action == 1 else 0.0)
            return CommandResult(result=ACCEPTED)
        return CommandResult(result=UNSUPPORTED)

    def _set_mode_from(self, base_mode: int, custom: int, sub: int) -> CommandResult:
        if not base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return CommandResult(result=UNSUPPORTED, text="Mode: only custom modes")
        if self.flavour.name == "px4":
            custom = (custom << 16) | (sub << 24)
        mode = self.flavour.mode_from_custom(custom)
        if mode is None:
            return CommandResult(result=DENIED if self.flavour.name == "px4" else FAILED,
                                 text=f"Mode: unknown custom mode {custom}")
        return self.fc.set_mode(mode)

    def _on_set_mode(self, msg: Any, now: float) -> None:
        if self.flavour.name == "px4":
            mode = self.flavour.mode_from_custom(msg.custom_mode)
            res = self.fc.set_mode(mode) if mode else CommandResult(result=DENIED)
        else:
            res = self._set_mode_from(msg.base_mode, msg.custom_mode, 0)
        # SET_MODE is acknowledged as DO_SET_MODE by both autopilots.
        self._ack(msg, mavlink.MAV_CMD_DO_SET_MODE, res)

    # ---------------------------------------------------------------------- parameters

    def _param_value(self, name: str) -> Any:
        spec = self.params.spec(name)
        raw = encode_param_value(self.params.get(name), spec.param_type,
                                 bytewise=self.flavour.param_bytewise)
        return mavlink.MAVLink_param_value_message(
            name.encode(), raw, spec.param_type, len(self.params), self.params.index(name))

    def _on_param_request_list(self, msg: Any, now: float) -> None:
        for name in self.params.names:
            self._send(self._param_value(name))

    def _on_param_request_read(self, msg: Any, now: float) -> None:
        name = self.params.name_at(msg.param_index) if msg.param_index >= 0 else text_field(
            msg.param_id)
        if name is None or name not in self.params:
            self.counters["unknown_param"] += 1  # dropped: no stack answers (see flavour.py)
            return
        self._send(self._param_value(name))

    def _on_param_set(self, msg: Any, now: float) -> None:
        name = text_field(msg.param_id)
        if name not in self.params:
            self.counters["unknown_param"] += 1
            return
        spec = self.params.spec(name)
        value = decode_param_value(msg.param_value, spec.param_type,
                                   bytewise=self.flavour.param_bytewise)
        if not math.isfinite(value):
            self.counters["bad_param_value"] += 1
            return
        self.params.set(name, value)
        self.fc.on_params_changed()
        self._send(self._param_value(name))

    def _guided_from_mask(self, mask: int, pos: tuple[float, float, float] | None,
                          vel: tuple[float, float, float], yaw: float, now: float) -> None:
        use_pos = pos is not None and not mask & 0b111
        use_vel = not mask & 0b111000
        if use_pos and pos is not None:
            finite_field(pos, "position")
        if use_vel:
            finite_field(vel, "velocity")
        target = GuidedTarget(
            position_ned_m=pos if use_pos else None,
            velocity_ned_m_s=vel if use_vel and not use_pos else None,
            yaw_rad=None if mask & 1024 or not math.isfinite(yaw) else yaw,
            t_s=now,
        )
        if target.position_ned_m is None and target.velocity_ned_m_s is None:
            self.counters["position_target_ignored"] += 1
            return
        self.fc.set_guided_target(target)

    def _on_position_target_local(self, msg: Any, now: float) -> None:
        frame = msg.coordinate_frame
        st = self.fc.state
        pos = (msg.x, msg.y, msg.z)
        vel = (msg.vx, msg.vy, msg.vz)
        if frame in (mavlink.MAV_FRAME_BODY_NED, mavlink.MAV_FRAME_BODY_OFFSET_NED,
                     mavlink.MAV_FRAME_BODY_FRD):
            c, s = math.cos(st.yaw_rad), math.sin(st.yaw_rad)
            pos = (c * pos[0] - s * pos[1], s * pos[0] + c * pos[1], pos[2])
            vel = (c * vel[0] - s * vel[1], s * vel[0] + c * vel[1], vel[2])
        if frame in (mavlink.MAV_FRAME_LOCAL_OFFSET_NED, mavlink.MAV_FRAME_BODY_NED,
                     mavlink.MAV_FRAME_BODY_OFFSET_NED, mavlink.MAV_FRAME_BODY_FRD):
            here = st.position_ned_m
            pos = (here[0] + pos[0], here[1] + pos[1], here[2] + pos[2])
        self._guided_from_mask(msg.type_mask, pos, vel, msg.yaw, now)

    def _on_position_target_global(self, msg: Any, now: float) -> None:
        alt_rel = commanded_alt_rel_m(msg.coordinate_frame, msg.alt, self.config.home)
        pos = None
        if not msg.type_mask & 0b111:
            lat, lon = lat_lon_field(msg.lat_int / 1e7, msg.lon_int / 1e7)
            pos = self._geo_to_ned(lat, lon, finite_field((alt_rel,), "alt")[0])
        self._guided_from_mask(msg.type_mask, pos, (msg.vx, msg.vy, msg.vz), msg.yaw, now)

    # ---------------------------------------------------------------------- PING, TIMESYNC

    def _on_ping(self, msg: Any, now: float) -> None:
        if msg.target_system == 0 and msg.target_component == 0:  # a request, not a reply
            self._send(mavlink.MAVLink_ping_message(
                msg.time_usec, msg.seq, msg.get_srcSystem(), msg.get_srcComponent()))

    def _on_timesync(self, msg: Any, now: float) -> None:
        if msg.tc1 == 0:
            self._send(mavlink.MAVLink_timesync_message(int(now * 1e9), msg.ts1))
