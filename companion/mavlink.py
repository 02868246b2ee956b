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

Where it lives: the converter in :mod:`companion.mavlink_convert`, commands and settings in
:mod:`companion.mavlink_commands`, the thread in :mod:`companion.mavlink_reader`; this module
is the asyncio face (:class:`MavlinkService`) and re-exports the names callers import.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable
from typing import Any

from companion.mavlink_commands import (
    DEFAULT_STREAM_RATES_HZ,
    ArmCommand,
    Command,
    CommandError,
    MavlinkSettings,
    ParamReadCommand,
    SendCommand,
    SetModeCommand,
    describe_command,
    describe_connect_error,
)
from companion.mavlink_convert import MavlinkConverter, decode_param_value
from companion.mavlink_reader import Clock, MavlinkReader
from companion.telemetry import Sample, TelemetryState

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
            raise CommandError(f"{describe_command(command)}: MAVLink service not running")
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
