"""The thread that owns the pymavlink connection (see :mod:`companion.mavlink`)."""


from __future__ import annotations

import concurrent.futures
import contextlib
import logging
import queue
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from companion.mavlink_commands import (
    ArmCommand,
    Command,
    CommandError,
    MavlinkSettings,
    ParamReadCommand,
    SendCommand,
    SetModeCommand,
    command_id,
    describe_command,
    describe_connect_error,
    fail_command,
    unconfirmed,
)
from companion.mavlink_connect import default_connect as _default_connect
from companion.mavlink_convert import (
    MAV_AUTOPILOT_INVALID,
    MAV_CMD_COMPONENT_ARM_DISARM,
    MAV_CMD_DO_SET_MODE,
    MAV_CMD_SET_MESSAGE_INTERVAL,
    MAV_DATA_STREAM_ALL,
    MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
    MAV_RESULT_ACCEPTED,
    MAV_STATE_ACTIVE,
    MAV_TYPE_ONBOARD_CONTROLLER,
    MavlinkConverter,
)
from companion.mavlink_hint import sharing_hint, silence_hint
from companion.mavlink_watch import StreamWatch, stalled_s, streams_for
from companion.telemetry import (
    CommandAckSample,
    HeartbeatSample,
    LinkStateSample,
    ParamSample,
    Sample,
)

log = logging.getLogger("companion.mavlink")  # one logger name for the whole link

Clock = Callable[[], float]
Post = Callable[[Sample], None]


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
        self._silent = False
        """Reopening a link that never brought a HEARTBEAT: said once, not per reopening."""
        self._t_lost: float | None = None
        """When the autopilot's link was lost (None: up, or never heard)."""
        self.counters: dict[str, int] = {
            "connects": 0, "connect_errors": 0, "heartbeat_losses": 0, "messages": 0,
            "samples": 0, "bad_messages": 0, "stream_requests": 0, "stream_fallbacks": 0,
            "stalls": 0,
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
        self._unparsable = 0  # BAD_DATA since this opening (for the silence hint)
        self._t_last_heartbeat: float | None = None
        self._t_last_look: float | None = None
        self._forgave = False
        self._t_next_heartbeat = 0.0
        self._stream_deadline: float | None = None
        self._stream_acks = 0
        self._streams_asked = 0
        self._pending: list[_Pending] = []
        fastest = max(self.settings.stream_rates_hz.values(), default=0.0)
        self._watch = StreamWatch(silence_s=max(self.settings.heartbeat_timeout_s,
                                                2.5 / fastest if fastest > 0 else 0.0))

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
        self._t_opened = self._t_last_look = self._clock()
        self._t_next_heartbeat = 0.0
        if self._silent:  # said once at INFO when the waiting began (_lose)
            log.debug("mavlink connection reopened: %s (no HEARTBEAT yet)", self.settings.url)
        else:
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
            shared = sharing_hint(self.settings.url)  # a serial port another program reads
            log.warning("mavlink receive failed: %s%s", exc, f" ({shared})" if shared else "")
            return self._lose(conn, f"receive failed: {exc}")
        now = self._clock()
        self._forgive_stall(now)
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
            self._unparsable += 1
            return
        if self._connected and (msg.get_srcSystem(), msg.get_srcComponent()) == (
                self._converter.target_system, self._converter.target_component):
            rebooted = self._watch.rebooted(msg, now)
            if rebooted is not None:  # its fix, origin and streams are new: start afresh
                log.warning("mavlink: %s: asking for its streams again", rebooted)
                self._emit(LinkStateSample(t=now, connected=False, reason=rebooted))
                self._emit(LinkStateSample(t=now, connected=True, reason=rebooted))
                self._request_streams(conn, now)
        sample = self._converter.convert(msg, now=now)
        if sample is None:
            return
        if isinstance(sample, HeartbeatSample):
            self._t_last_heartbeat, self._forgave = now, False
            if not self._connected:
                self._connected = True
                self._silent = False
                # each time: after a loss the journal's last word was "link lost"
                back = "" if self._t_lost is None else f": back after {now - self._t_lost:.1f} s"
                self._t_lost = None
                log.info("mavlink: HEARTBEAT from system %d on %s%s", sample.system_id,
                         self.settings.url, back)
                self._emit(LinkStateSample(t=now, connected=True,
                                           reason=f"heartbeat from system {sample.system_id}"))
                self._request_streams(conn, now)
        elif isinstance(sample, CommandAckSample) and not sample.answers(
                self.settings.source_system, self.settings.source_component):
            self._emit(sample)
            return  # another client's answer (a GCS on this link): never ours to count
        elif isinstance(sample, CommandAckSample) and sample.command == \
                MAV_CMD_SET_MESSAGE_INTERVAL and sample.result == MAV_RESULT_ACCEPTED:
            self._stream_acks += 1
        self._emit(sample)
        self._resolve_pending(sample)

    def _emit(self, sample: Sample) -> None:
        self.counters["samples"] += 1
        self._post(sample)

    def _forgive_stall(self, now: float) -> None:
        """Time the reader did not run is not the link's silence (docs/companion.md); once
        per HEARTBEAT, so a reader that stalls again and again cannot hide a dead link."""
        unseen = stalled_s(self._t_last_look, now, self.settings.recv_timeout_s)
        self._t_last_look = now
        if not unseen or (unseen > 0 and self._forgave):
            return
        self._forgave = unseen > 0
        if unseen > 0:
            self.counters["stalls"] += 1
            log.warning("mavlink: the reader did not run for %.1f s (this computer was busy or "
                        "suspended, or its clock was set): not the link's silence", unseen)
        else:  # the link's timers follow the clock back
            log.warning("mavlink: the clock went back %.1f s", -unseen)
        self._t_opened += unseen
        if self._t_last_heartbeat is not None:
            self._t_last_heartbeat += unseen
        if self._watch.t_last_stream is not None:
            self._watch.t_last_stream += unseen
        if self._stream_deadline is not None:
            self._stream_deadline += unseen
        for pending in self._pending:
            pending.deadline += unseen

    def _check_timers(self, conn: Any, now: float) -> Any:
        timeout = self.settings.heartbeat_timeout_s
        last = self._t_last_heartbeat if self._t_last_heartbeat is not None else self._t_opened
        if now - last > timeout:
            return self._lose(conn, f"no HEARTBEAT for {now - last:.1f} s")
        if self._connected and self._watch.silent(now):
            log.log(logging.DEBUG if self._watch.told else logging.WARNING,
                    "mavlink: HEARTBEATs but none of the requested streams for %.1f s "
                    "(the autopilot rebooted, or a GCS on this link stopped them): asking "
                    "again", now - (self._watch.t_last_stream or now))
            self._watch.told = True  # once per silence, not once per request
            self._request_streams(conn, now)
        if self._stream_deadline is not None and now >= self._stream_deadline:
            self._stream_deadline = None
            if self._stream_acks < self._streams_asked:
                self._request_data_stream(conn)
        for pending in [p for p in self._pending if now >= p.deadline]:
            self._pending.remove(pending)
            fail_command(pending.command, unconfirmed(pending.command))
        return conn

    def _lose(self, conn: Any, reason: str) -> None:
        """Close the connection; ``_main`` reopens it after ``reconnect_delay_s``."""
        if self._connected:
            self.counters["heartbeat_losses"] += 1
            self._t_lost = self._clock()
            self._emit(LinkStateSample(t=self._t_lost, connected=False, reason=reason))
            log.warning("mavlink link lost: %s", reason)
        elif not self._silent:  # never heard: close and reopen (serial re-enumeration, ...)
            self._silent = True
            log.info("mavlink: %s on %s: closing it and reopening every ~%g s until an "
                     "autopilot HEARTBEAT arrives (%s)", reason, self.settings.url,
                     self.settings.heartbeat_timeout_s + self.settings.reconnect_delay_s,
                     silence_hint(self.settings.url, own_socket_open=True,
                                  unparsable=self._unparsable,
                                  baud=self.settings.baud))
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
        wanted = streams_for(self._converter.autopilot, self.settings.stream_rates_hz)
        for name, rate_hz in wanted.items():
            msg_id = getattr(dialect, f"MAVLINK_MSG_ID_{name}")
            interval_us = 1e6 / rate_hz if rate_hz > 0 else -1
            conn.mav.command_long_send(target, component, MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                       msg_id, interval_us, 0, 0, 0, 0, 0)
        self.counters["stream_requests"] += 1
        self._watch.asked(wanted, wanted.values(), now)
        self._stream_acks = 0
        self._streams_asked = len(wanted)
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
                fail_command(command, f"{describe_command(command)}: no autopilot connected")
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
                    and sample.command == command_id(command):
                self._pending.remove(pending)
                fail_command(command, f"{describe_command(command)}: refused by the autopilot "
                             f"(MAV_RESULT {sample.result})")
                continue
            if done is not _UNSET:
                self._pending.remove(pending)
                command.future.set_result(done)

    def _fail_pending(self, reason: str) -> None:
        for pending in self._pending:
            fail_command(pending.command, f"{describe_command(pending.command)}: {reason}")
        self._pending = []
        while True:
            try:
                command = self._commands.get_nowait()
            except queue.Empty:
                return
            if command.future.set_running_or_notify_cancel():
                fail_command(command, f"{describe_command(command)}: {reason}")


_UNSET = object()
