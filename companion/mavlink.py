"""The MAVLink link to the autopilot: one thread owns the pymavlink connection.

pymavlink blocks and keeps process-wide state, so it never touches the event loop
(STYLE.md, "Handle MAVLink in one thread"). :class:`MavlinkReader` runs a thread that

* loops on ``recv_match(blocking=True, timeout=...)`` and checks a ``threading.Event`` to stop,
* converts each message at once into a frozen sample in SI units (:class:`MavlinkConverter`,
  a pure converter that can be tested without a socket), stamped with the injected clock,
* hands each sample to ``post`` (the app passes ``loop.call_soon_threadsafe(state.apply, s)``),
* drains a ``queue.Queue`` of commands (mode change, arm, parameter read) whose results come
  back as ``concurrent.futures.Future``\\ s,
* asks for streams with MAV_CMD_SET_MESSAGE_INTERVAL and falls back to REQUEST_DATA_STREAM
  when the autopilot does not accept it (ArduPilot sends nothing on a second link until asked;
  PX4 streams unasked),
* sends its own HEARTBEAT as MAV_TYPE_ONBOARD_CONTROLLER once a second,
* declares the link down after ``heartbeat_timeout_s`` without an autopilot HEARTBEAT, closes
  the connection and reopens it (serial re-enumeration, TCP reconnect, UDP rebind) until the
  vehicle is back, without restarting the process.

A mode change or arming is confirmed only when a HEARTBEAT shows it, never by COMMAND_ACK
alone. PX4 sends integer parameters byte-encoded in the float of PARAM_VALUE; ArduPilot sends
their numeric value; :class:`MavlinkConverter` decodes both.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import errno
import logging
import math
import queue
import struct
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from companion.telemetry import (
    AttitudeSample,
    BatterySample,
    CommandAckSample,
    EstimatorSample,
    GpsSample,
    HeartbeatSample,
    LinkStateSample,
    ParamSample,
    PositionSample,
    Sample,
    StatusTextSample,
    SystemTimeSample,
    TelemetryState,
)

__all__ = [
    "DEFAULT_STREAM_RATES_HZ",
    "ArmCommand",
    "Command",
    "CommandError",
    "MavlinkConverter",
    "MavlinkReader",
    "MavlinkService",
    "MavlinkSettings",
    "ParamReadCommand",
    "SetModeCommand",
    "decode_param_value",
    "describe_connect_error",
]

log = logging.getLogger(__name__)

# MAVLink enum values used below (common.xml), spelled out so this module can be read
# and its converter tested without pymavlink's process-wide dialect.
MAV_AUTOPILOT_GENERIC = 0
MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_AUTOPILOT_INVALID = 8
MAV_AUTOPILOT_PX4 = 12
MAV_TYPE_ONBOARD_CONTROLLER = 18
MAV_TYPE_GCS = 6
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
ESTIMATOR_NOT_TRUSTED = 128 | 1024 | 32768
"""ESTIMATOR_CONST_POS_MODE, ESTIMATOR_UNINITIALIZED, ESTIMATOR_GPS_GLITCH."""
MAV_COMP_ID_ONBOARD_COMPUTER = 191
MAV_PARAM_TYPE_SIGNED = {2, 4, 6}  # INT8, INT16, INT32
MAV_PARAM_TYPE_UNSIGNED = {1, 3, 5}  # UINT8, UINT16, UINT32

AUTOPILOT_NAMES = {
    MAV_AUTOPILOT_GENERIC: "generic",
    MAV_AUTOPILOT_ARDUPILOTMEGA: "ardupilot",
    MAV_AUTOPILOT_PX4: "px4",
}

DEFAULT_STREAM_RATES_HZ: Mapping[str, float] = {
    "GLOBAL_POSITION_INT": 5.0,
    "ATTITUDE": 10.0,
    "SYS_STATUS": 1.0,
    "BATTERY_STATUS": 1.0,
    "GPS_RAW_INT": 1.0,
    "SYSTEM_TIME": 1.0,
    "EKF_STATUS_REPORT": 1.0,  # ArduPilot: has the estimator an origin (position valid)?
    "ESTIMATOR_STATUS": 1.0,  # PX4: the same flags
}

Clock = Callable[[], float]
Post = Callable[[Sample], None]


class CommandError(Exception):
    """A command the vehicle did not carry out; the text says which and why."""


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

    It keeps only what the conversion needs: which system is the autopilot (the first
    HEARTBEAT whose ``autopilot`` is not MAV_AUTOPILOT_INVALID) and its family, for mode
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
        if self.target_system is None or msg.get_srcSystem() != self.target_system:
            return None
        handler = _HANDLERS.get(kind)
        if handler is None:
            return None
        return handler(self, msg, now)

    def _heartbeat(self, msg: Any, now: float) -> HeartbeatSample | None:
        if msg.autopilot == MAV_AUTOPILOT_INVALID or msg.type in (
            MAV_TYPE_GCS, MAV_TYPE_ONBOARD_CONTROLLER):
            return None
        system = msg.get_srcSystem()
        if self.target_system is None:
            self.target_system = system
            self.target_component = msg.get_srcComponent()
        elif system != self.target_system:
            return None
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
        flags = int(msg.flags)
        ok = bool(flags & ESTIMATOR_POS_HORIZ_ABS) and not flags & ESTIMATOR_NOT_TRUSTED
        return EstimatorSample(t=now, source=msg.get_type(), flags=flags, position_ok=ok)

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
        return CommandAckSample(t=now, command=msg.command, result=msg.result)


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


def _mode_name(msg: Any) -> str:
    from pymavlink import mavutil

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


@dataclass(kw_only=True, eq=False)
class Command:
    """A request for the reader thread; ``future`` gets the result (or a CommandError)."""

    timeout_s: float = 5.0
    future: concurrent.futures.Future[Any] = field(default_factory=concurrent.futures.Future)


@dataclass(kw_only=True, eq=False)
class SetModeCommand(Command):
    """Change flight mode by name; done when a HEARTBEAT shows the new mode."""

    mode: str


@dataclass(kw_only=True, eq=False)
class ArmCommand(Command):
    """Arm or disarm; done when a HEARTBEAT shows the armed flag."""

    arm: bool = True


@dataclass(kw_only=True, eq=False)
class ParamReadCommand(Command):
    """Read one parameter; the result is its decoded value."""

    name: str


@dataclass(kw_only=True, eq=False)
class SendCommand(Command):
    """send one message as is (ADSB_VEHICLE); done once written."""

    message: Any


@dataclass(frozen=True, slots=True, kw_only=True)
class MavlinkSettings:
    url: str
    """pymavlink connection string: ``udpin:0.0.0.0:14550``, ``tcp:host:5760``,
    ``/dev/serial0,921600``..."""
    source_system: int = 1
    source_component: int = MAV_COMP_ID_ONBOARD_COMPUTER
    heartbeat_timeout_s: float = 3.0
    heartbeat_interval_s: float = 1.0
    recv_timeout_s: float = 0.5
    reconnect_delay_s: float = 1.0
    stream_ack_timeout_s: float = 1.5
    stream_rates_hz: Mapping[str, float] = field(
        default_factory=lambda: dict(DEFAULT_STREAM_RATES_HZ))
    baud: int = 115200


@dataclass(kw_only=True)
class _Pending:
    command: Command
    deadline: float


class MavlinkReader:
    """The thread that owns one pymavlink connection (see the module docstring).

    ``connect`` builds the connection (default: ``mavutil.mavlink_connection``) so tests can
    count reopenings; ``clock`` is the fleet clock (``time.time`` in production).
    """

    def __init__(
        self,
        settings: MavlinkSettings,
        *,
        clock: Clock,
        post: Post,
        connect: Callable[[MavlinkSettings], Any] | None = None,
    ) -> None:
        self.settings = settings
        self._clock = clock
        self._post = post
        self._connect = connect or _default_connect
        self._stop = threading.Event()
        self._commands: queue.Queue[Command] = queue.Queue()
        self._thread: threading.Thread | None = None
        self.done: concurrent.futures.Future[None] = concurrent.futures.Future()
        self.last_error: str | None = None
        """Why the last attempt to open the link failed, in plain words (None: it opened)."""
        self.counters: dict[str, int] = {
            "connects": 0, "connect_errors": 0, "heartbeat_losses": 0, "messages": 0,
            "samples": 0, "bad_messages": 0, "stream_requests": 0, "stream_fallbacks": 0,
        }
        self._reset_link_state()

    # -- public API (any thread) --------------------------------------------------------

    def start(self) -> None:
        if self._thread is not None:
            raise RuntimeError("MavlinkReader already started")
        self._thread = threading.Thread(target=self._main, name="mavlink", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()

    def join(self, timeout: float | None = None) -> None:
        if self._thread is not None:
            self._thread.join(timeout)

    def submit(self, command: Command) -> concurrent.futures.Future[Any]:
        """Queue a command for the thread; returns its future."""
        self._commands.put(command)
        return command.future

    # -- thread -------------------------------------------------------------------------

    def _reset_link_state(self) -> None:
        self._converter = MavlinkConverter()
        self._connected = False
        self._t_opened = 0.0
        self._t_last_heartbeat: float | None = None
        self._t_next_heartbeat = 0.0
        self._stream_deadline: float | None = None
        self._stream_acks = 0
        self._pending: list[_Pending] = []

    def _main(self) -> None:
        conn: Any = None
        try:
            while not self._stop.is_set():
                if conn is None:
                    conn = self._open()
                    if conn is None:
                        self._stop.wait(self.settings.reconnect_delay_s)
                        continue
                conn = self._step(conn)
        except BaseException as exc:
            log.exception("mavlink thread failed")
            if not self.done.done():
                self.done.set_exception(exc)
        else:
            if not self.done.done():  # cancelled by the awaiting side: nothing to report
                self.done.set_result(None)
        finally:
            self._fail_pending("MAVLink reader stopped")
            if conn is not None:
                with contextlib.suppress(OSError):
                    conn.close()

    def _open(self) -> Any:
        try:
            conn = self._connect(self.settings)
        except (OSError, ValueError, OverflowError, ImportError) as exc:
            # refused, no such device, port in use, no permission, pyserial missing...
            self.counters["connect_errors"] += 1
            error = describe_connect_error(self.settings.url, exc)
            # Once per cause, not once per retry: a Pi waiting for its autopilot would
            # otherwise write a warning a second to the journal for hours.
            level = logging.DEBUG if error == self.last_error else logging.WARNING
            log.log(level, "mavlink connect %s failed: %s", self.settings.url, error)
            self.last_error = error
            return None
        self.last_error = None
        self.counters["connects"] += 1
        self._t_opened = self._clock()
        self._t_next_heartbeat = 0.0
        log.info("mavlink connection opened: %s", self.settings.url)
        return conn

    def _step(self, conn: Any) -> Any:
        """One round: commands, own heartbeat, one receive, timers. Returns the connection
        to keep (``None`` to reopen)."""
        now = self._clock()
        try:
            # A write fails too when the line goes away (a USB autopilot unplugged, a serial
            # adapter re-enumerating, the pty's other end closed): lose the link, reopen.
            self._drain_commands(conn, now)
            if now >= self._t_next_heartbeat:
                conn.mav.heartbeat_send(MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID, 0,
                                        0, MAV_STATE_ACTIVE)
                self._t_next_heartbeat = now + self.settings.heartbeat_interval_s
        except OSError as exc:
            log.warning("mavlink send failed: %s", exc)
            return self._lose(conn, f"send failed: {exc}")
        try:
            msg = conn.recv_match(blocking=True, timeout=self.settings.recv_timeout_s)
        except OSError as exc:
            log.warning("mavlink receive failed: %s", exc)
            return self._lose(conn, f"receive failed: {exc}")
        now = self._clock()
        try:
            if msg is not None:
                self._handle(conn, msg, now)  # may answer (stream requests)
            return self._check_timers(conn, now)
        except OSError as exc:
            log.warning("mavlink send failed: %s", exc)
            return self._lose(conn, f"send failed: {exc}")

    def _handle(self, conn: Any, msg: Any, now: float) -> None:
        self.counters["messages"] += 1
        if msg.get_type() == "BAD_DATA":
            self.counters["bad_messages"] += 1
            return
        sample = self._converter.convert(msg, now=now)
        if sample is None:
            return
        if isinstance(sample, HeartbeatSample):
            self._t_last_heartbeat = now
            if not self._connected:
                self._connected = True
                self._emit(LinkStateSample(t=now, connected=True,
                                           reason=f"heartbeat from system {sample.system_id}"))
                self._request_streams(conn, now)
        elif isinstance(sample, CommandAckSample) and sample.command == \
                MAV_CMD_SET_MESSAGE_INTERVAL and sample.result == MAV_RESULT_ACCEPTED:
            self._stream_acks += 1
        self._emit(sample)
        self._resolve_pending(sample)

    def _emit(self, sample: Sample) -> None:
        self.counters["samples"] += 1
        self._post(sample)

    def _check_timers(self, conn: Any, now: float) -> Any:
        timeout = self.settings.heartbeat_timeout_s
        last = self._t_last_heartbeat if self._t_last_heartbeat is not None else self._t_opened
        if now - last > timeout:
            return self._lose(conn, f"no HEARTBEAT for {now - last:.1f} s")
        if self._stream_deadline is not None and now >= self._stream_deadline:
            self._stream_deadline = None
            if self._stream_acks < len(self.settings.stream_rates_hz):
                self._request_data_stream(conn)
        for pending in [p for p in self._pending if now >= p.deadline]:
            self._pending.remove(pending)
            _fail(pending.command, f"{_describe(pending.command)}: not confirmed by HEARTBEAT "
                                   f"within {pending.command.timeout_s} s")
        return conn

    def _lose(self, conn: Any, reason: str) -> None:
        """Close the connection; ``_main`` reopens it after ``reconnect_delay_s``."""
        if self._connected:
            self.counters["heartbeat_losses"] += 1
            self._emit(LinkStateSample(t=self._clock(), connected=False, reason=reason))
            log.warning("mavlink link lost: %s", reason)
        self._fail_pending(f"link lost: {reason}")
        with contextlib.suppress(OSError):
            conn.close()
        self._reset_link_state()
        self._stop.wait(self.settings.reconnect_delay_s)
        return None

    # -- streams ------------------------------------------------------------------------

    def _request_streams(self, conn: Any, now: float) -> None:
        """MAV_CMD_SET_MESSAGE_INTERVAL for each wanted message (fallback on no ACK)."""
        from pymavlink.dialects.v20 import ardupilotmega as dialect  # common + EKF_STATUS_REPORT

        target = self._converter.target_system or 1
        component = self._converter.target_component or 1
        for name, rate_hz in self.settings.stream_rates_hz.items():
            msg_id = getattr(dialect, f"MAVLINK_MSG_ID_{name}")
            interval_us = 1e6 / rate_hz if rate_hz > 0 else -1
            conn.mav.command_long_send(target, component, MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                       msg_id, interval_us, 0, 0, 0, 0, 0)
        self.counters["stream_requests"] += 1
        self._stream_acks = 0
        self._stream_deadline = now + self.settings.stream_ack_timeout_s

    def _request_data_stream(self, conn: Any) -> None:
        rate = max(1, round(max(self.settings.stream_rates_hz.values(), default=1.0)))
        conn.mav.request_data_stream_send(self._converter.target_system or 1,
                                          self._converter.target_component or 1,
                                          MAV_DATA_STREAM_ALL, rate, 1)
        self.counters["stream_fallbacks"] += 1
        log.info("SET_MESSAGE_INTERVAL not acknowledged; sent REQUEST_DATA_STREAM at %d Hz", rate)

    # -- commands -----------------------------------------------------------------------

    def _drain_commands(self, conn: Any, now: float) -> None:
        while True:
            try:
                command = self._commands.get_nowait()
            except queue.Empty:
                return
            if not command.future.set_running_or_notify_cancel():
                continue
            if not self._connected:
                _fail(command, f"{_describe(command)}: no autopilot connected")
                continue
            try:
                self._send_command(conn, command)
            except CommandError as exc:
                command.future.set_exception(exc)
                continue
            if isinstance(command, SendCommand):  # nothing to wait for
                command.future.set_result(None)
                continue
            self._pending.append(_Pending(command=command, deadline=now + command.timeout_s))

    def _send_command(self, conn: Any, command: Command) -> None:
        target = self._converter.target_system or 1
        component = self._converter.target_component or 1
        if isinstance(command, SetModeCommand):
            base_mode, custom_mode, sub_mode = self._mode_numbers(command.mode)
            conn.mav.command_long_send(target, component, MAV_CMD_DO_SET_MODE, 0,
                                       base_mode, custom_mode, sub_mode, 0, 0, 0, 0)
        elif isinstance(command, ArmCommand):
            conn.mav.command_long_send(target, component, MAV_CMD_COMPONENT_ARM_DISARM, 0,
                                       1 if command.arm else 0, 0, 0, 0, 0, 0, 0)
        elif isinstance(command, ParamReadCommand):
            conn.mav.param_request_read_send(target, component, command.name.encode(), -1)
        elif isinstance(command, SendCommand):
            conn.mav.send(command.message)
        else:
            raise CommandError(f"unknown command {command!r}")

    def _mode_numbers(self, mode: str) -> tuple[int, int, int]:
        from pymavlink import mavutil

        if self._converter.autopilot == "px4":
            entry = mavutil.px4_map.get(mode)
            if entry is None:
                raise CommandError(f"set mode {mode!r}: PX4 has no such mode "
                                   f"(known: {', '.join(sorted(mavutil.px4_map))})")
            return int(entry[0]), int(entry[1]), int(entry[2])
        names = mavutil.mode_mapping_byname(self._converter.vehicle_type)
        if not names or mode not in names:
            raise CommandError(f"set mode {mode!r}: unknown for vehicle type "
                               f"{self._converter.vehicle_type} (known: "
                               f"{', '.join(sorted(names or {}))})")
        return MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, int(names[mode]), 0

    def _resolve_pending(self, sample: Sample) -> None:
        for pending in list(self._pending):
            command = pending.command
            done: Any = _UNSET
            if isinstance(sample, HeartbeatSample):
                if isinstance(command, SetModeCommand) and sample.mode == command.mode:
                    done = sample.mode
                elif isinstance(command, ArmCommand) and sample.armed == command.arm:
                    done = sample.armed
            elif isinstance(sample, ParamSample) and isinstance(command, ParamReadCommand):
                if sample.name == command.name:
                    done = sample.value
            elif isinstance(sample, CommandAckSample) and sample.result != MAV_RESULT_ACCEPTED \
                    and sample.command == _command_id(command):
                self._pending.remove(pending)
                _fail(command, f"{_describe(command)}: refused by the autopilot "
                               f"(MAV_RESULT {sample.result})")
                continue
            if done is not _UNSET:
                self._pending.remove(pending)
                command.future.set_result(done)

    def _fail_pending(self, reason: str) -> None:
        for pending in self._pending:
            _fail(pending.command, f"{_describe(pending.command)}: {reason}")
        self._pending = []
        while True:
            try:
                command = self._commands.get_nowait()
            except queue.Empty:
                return
            if command.future.set_running_or_notify_cancel():
                _fail(command, f"{_describe(command)}: {reason}")


_UNSET = object()


def _command_id(command: Command) -> int | None:
    if isinstance(command, SetModeCommand):
        return MAV_CMD_DO_SET_MODE
    if isinstance(command, ArmCommand):
        return MAV_CMD_COMPONENT_ARM_DISARM
    return None


def _describe(command: Command) -> str:
    if isinstance(command, SetModeCommand):
        return f"set mode {command.mode}"
    if isinstance(command, ArmCommand):
        return "arm" if command.arm else "disarm"
    if isinstance(command, ParamReadCommand):
        return f"read parameter {command.name}"
    return type(command).__name__


def _fail(command: Command, text: str) -> None:
    if not command.future.done():
        command.future.set_exception(CommandError(text))


def describe_connect_error(url: str, exc: BaseException) -> str:
    """Why opening ``url`` failed, in words a user can act on (errno kept for searching)."""
    if isinstance(exc, ImportError):
        return (f"{exc} (serial links need pyserial: pip install pyserial)"
                if "serial" in str(exc) else str(exc))
    errno_ = getattr(exc, "errno", None)
    device = url.partition(",")[0]
    serial = device.startswith("/") or device.startswith("COM")
    code = f"[Errno {errno_}] " if isinstance(errno_, int) else ""
    if serial and errno_ == errno.ENOENT:
        return (f"{code}no such device {device}: is the autopilot connected and the UART "
                "enabled (Raspberry Pi: raspi-config, serial port on, login shell off)?")
    if serial and errno_ in (errno.EACCES, errno.EPERM):
        return (f"{code}permission denied on {device}: add the user to the dialout group "
                "(sudo usermod -aG dialout $USER, then log in again)")
    if serial and errno_ == errno.EBUSY:
        return f"{code}{device} is busy: another program has it open"
    if serial and errno_ == errno.ENOTTY:
        return f"{code}{device} is not a serial device"
    if errno_ == errno.EADDRINUSE:
        return (f"{code}Address already in use: another program already listens on "
                f"{url.partition(':')[2]}; stop it or pick another port")
    if errno_ == errno.EADDRNOTAVAIL:
        return f"{code}Cannot assign requested address: this machine has no such address"
    if errno_ == errno.ECONNREFUSED:
        return f"{code}Connection refused: nothing listens at {url.partition(':')[2]}"
    if isinstance(exc, OverflowError):
        return f"bad port in {url}: {exc}"
    if serial and "Inappropriate ioctl" in str(exc):  # pyserial hides this errno in its text
        return f"[Errno {errno.ENOTTY}] {device} is not a serial device"
    return str(exc) or type(exc).__name__


def _default_connect(settings: MavlinkSettings) -> Any:
    from pymavlink import mavutil

    return mavutil.mavlink_connection(
        settings.url, baud=settings.baud, source_system=settings.source_system,
        source_component=settings.source_component, autoreconnect=False,
    )


class MavlinkService:
    """Asyncio face of :class:`MavlinkReader`: ``run()`` owns the thread, ``stop()`` ends it.

    Samples go to ``state.apply`` on the loop thread. Commands are awaitable methods that
    raise :class:`CommandError` when the vehicle does not confirm them.
    """

    def __init__(self, settings: MavlinkSettings, state: TelemetryState, *, clock: Clock,
                 connect: Callable[[MavlinkSettings], Any] | None = None) -> None:
        self.settings = settings
        self.state = state
        self._clock = clock
        self._connect = connect
        self.reader: MavlinkReader | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop_requested = False

    def _post(self, sample: Sample) -> None:
        loop = self._loop
        if loop is None:
            return
        with contextlib.suppress(RuntimeError):  # loop closed while the thread winds down
            loop.call_soon_threadsafe(self.state.apply, sample)

    async def run(self) -> None:
        if self._stop_requested:
            return
        self._loop = asyncio.get_running_loop()
        self.reader = MavlinkReader(self.settings, clock=self._clock, post=self._post,
                                    connect=self._connect)
        self.reader.start()
        try:
            await asyncio.wrap_future(self.reader.done)
        finally:
            self.reader.stop()
            await asyncio.to_thread(self.reader.join, 5.0)

    def stop(self) -> None:
        self._stop_requested = True
        if self.reader is not None:
            self.reader.stop()

    async def _command(self, command: Command) -> Any:
        if self.reader is None:
            raise CommandError(f"{_describe(command)}: MAVLink service not running")
        future = self.reader.submit(command)
        async with asyncio.timeout(command.timeout_s + 2 * self.settings.recv_timeout_s):
            return await asyncio.wrap_future(future)

    async def set_mode(self, mode: str, *, timeout_s: float = 5.0) -> None:
        snap = self.state.snapshot()
        if snap.mode == mode:
            return
        await self._command(SetModeCommand(mode=mode, timeout_s=timeout_s))

    async def arm(self, *, timeout_s: float = 5.0) -> None:
        snap = self.state.snapshot()
        if snap.autopilot == "ardupilot" and snap.mode in ("RTL", "LAND"):
            raise CommandError(f"arm: ArduPilot will not arm in {snap.mode}; change mode first")
        await self._command(ArmCommand(arm=True, timeout_s=timeout_s))

    def send_message(self, message: Any) -> None:
        """queue one message for the autopilot; fire and forget (a link that is
        down drops it, like the radio would)."""
        if self.reader is None:
            raise CommandError("MAVLink service not running")
        self.reader.submit(SendCommand(message=message, timeout_s=1.0))

    async def disarm(self, *, timeout_s: float = 5.0) -> None:
        await self._command(ArmCommand(arm=False, timeout_s=timeout_s))

    async def read_param(self, name: str, *, timeout_s: float = 5.0) -> int | float:
        value: int | float = await self._command(ParamReadCommand(name=name,
                                                                  timeout_s=timeout_s))
        return value
