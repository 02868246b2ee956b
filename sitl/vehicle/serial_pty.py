"""A simulated vehicle on a serial line: a pseudo-terminal instead of a UDP socket.

A Pixhawk's TELEM port wired to a Raspberry Pi UART is a byte stream, not datagrams: frames
arrive split or glued together, and the line carries at most ``baud / 10`` bytes per second
(8N1). :class:`PtySerialLink` gives one :class:`~sitl.vehicle.core.VehicleCore` that shape:
the client opens the pty's slave (``/dev/pts/N``, or a stable symlink to it) through
pyserial like a real UART; the vehicle side reads and writes the master.

Like ArduPilot, which skips a stream message when the UART's transmit buffer has no room,
stream frames that exceed the line's budget (a 4 KiB transmit buffer refilled at
``baud / 10`` B/s) are dropped and counted. The rest (HEARTBEAT, answers, STATUSTEXT, the
parameter and mission protocols) wait and go out as the line frees, first: ArduPilot defers
them, and sends a parameter list with at most 30 % of the line (``queued_param_send``), so a
GCS's parameter download on a 57600 line is paced, not lost, and the HEARTBEAT and the
streams keep coming.
Before, the fake dropped them too: 440 PARAM_VALUEs at once lost most of them and the
HEARTBEAT behind them. The wait is bounded (``BACKLOG_BYTES``; beyond it, counted drops).
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import termios
import tty
from collections import deque
from collections.abc import Callable, Hashable
from dataclasses import replace
from pathlib import Path

from sitl.vehicle.core import VehicleConfig, VehicleCore
from sitl.vehicle.links import DEFAULT_LINK
from sitl.vehicle.shell import CoreTimer, LinkGroup, SimClock, VehicleEndpoint, VehicleProtocol

__all__ = ["PtySerialLink", "start_serial_and_udp_vehicle", "start_serial_vehicle"]

TX_BUFFER_BYTES = 4096
BACKLOG_BYTES = 65536
"""Deferred frames waiting for the line (a parameter list of 900 PX4 parameters fits)."""
DEFERRED_IDS = frozenset({0, 4, 22, 39, 40, 44, 46, 47, 51, 73, 77, 111, 148, 244, 253})
"""HEARTBEAT, PING, PARAM_VALUE, the mission protocol (ITEM, REQUEST, COUNT, ITEM_REACHED,
ACK, REQUEST_INT, ITEM_INT), COMMAND_ACK, TIMESYNC, AUTOPILOT_VERSION, MESSAGE_INTERVAL,
STATUSTEXT: never skipped for a full line, only delayed."""
PARAM_VALUE = 22
PARAM_SHARE = 0.3
"""Of the line's rate a parameter list may take (ArduPilot's ``queued_param_send``)."""


def _message_id(frame: bytes) -> int:
    """The message id of one packed MAVLink 1 or 2 frame."""
    if frame[:1] == b"\xfd" and len(frame) >= 10:
        return int.from_bytes(frame[7:10], "little")
    return frame[5] if len(frame) > 5 else -1
_BAUD_CONSTANTS = {115200: termios.B115200, 57600: termios.B57600, 230400: termios.B230400,
                   460800: getattr(termios, "B460800", termios.B230400),
                   921600: getattr(termios, "B921600", termios.B230400)}


class PtySerialLink:
    """One vehicle behind a pseudo-terminal; ``path`` is what a client opens."""

    def __init__(self, core: VehicleCore, clock: SimClock, *, baud: int = 115200,
                 link: Path | None = None, tx_buffer_bytes: int = TX_BUFFER_BYTES,
                 channel: Hashable = DEFAULT_LINK, group: LinkGroup | None = None) -> None:
        if baud <= 0:
            raise ValueError(f"baud must be > 0, got {baud}")
        self.core = core
        self.clock = clock
        self.baud = baud
        self.link = link
        self.tx_buffer_bytes = tx_buffer_bytes
        self.counters = {"rx_bytes": 0, "tx_bytes": 0, "tx_dropped_frames": 0}
        self._master, self._slave = os.openpty()
        # Raw 8N1 both ways: no echo, no line editing, no CR/LF translation of binary frames.
        for fd in (self._master, self._slave):
            tty.setraw(fd)
        speed = _BAUD_CONSTANTS.get(baud)
        if speed is not None:  # nominal on a pty, but a client reading it back sees it
            attrs = termios.tcgetattr(self._slave)
            attrs[4] = attrs[5] = speed
            termios.tcsetattr(self._slave, termios.TCSANOW, attrs)
        os.set_blocking(self._master, False)
        # The vehicle keeps its own slave fd open: with no slave open, the master reads EIO
        # whenever the client closes and reopens the port (a companion reconnecting).
        self.tty_path = os.ttyname(self._slave)
        self.path = self.tty_path
        if link is not None:
            with contextlib.suppress(FileNotFoundError):
                if link.is_symlink():
                    link.unlink()
            link.symlink_to(self.tty_path)
            self.path = str(link)
        self._budget = float(tx_buffer_bytes)
        self._backlog: tuple[deque[bytes], deque[bytes]] = (deque(), deque())
        """Waiting frames: the rest first, then PARAM_VALUEs (ArduPilot sends parameters
        only into what is left of the UART's space)."""
        self._backlog_bytes = 0
        self._param_budget = 0.0
        self._t_budget = clock.loop.time()
        self.channel = channel
        """The core's link this line is (``link`` is the symlink's path)."""
        self.group = group
        self._timer = CoreTimer(core, clock, self.transmit) if group is None else None
        if group is not None:
            group.members.append(self.send_pending)
        self._closed = False

    def start(self) -> None:
        self.clock.loop.add_reader(self._master, self._on_readable)
        self.transmit()

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        if self._timer is not None:
            self._timer.cancel()
        if self.group is not None:
            self.group.cancel()
        self.clock.loop.remove_reader(self._master)
        for fd in (self._master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)
        if self.link is not None:
            with contextlib.suppress(OSError):
                if self.link.is_symlink() and os.readlink(self.link) == self.tty_path:
                    self.link.unlink()

    def _on_readable(self) -> None:
        try:
            data = os.read(self._master, 4096)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:  # EIO: no reader on the other side at this instant
            return
        if data:
            self.counters["rx_bytes"] += len(data)
            self.core.receive_datagram(data, ("serial", 0), self.clock(), self.channel)
            self.transmit()

    def _refill(self) -> None:
        now = self.clock.loop.time()
        rate = self.baud / 10.0
        self._budget = min(float(self.tx_buffer_bytes),
                           self._budget + (now - self._t_budget) * rate)
        self._param_budget = min(PARAM_SHARE * self.tx_buffer_bytes, self._param_budget
                                 + (now - self._t_budget) * rate * PARAM_SHARE)
        self._t_budget = now

    def transmit(self) -> None:
        if self.group is not None:
            self.group.transmit()
            return
        if self._closed:
            return
        self.send_pending()
        if self._timer is not None:
            self._timer.rearm()

    def send_pending(self) -> None:
        """Write this line's frames and the HEARTBEATs routed to it, within the budget."""
        if self._closed:
            return
        frames = self.core.datagrams_to_send(self.channel)
        # a line has one client: only what came on another link, never its own echo
        frames += [frame for sender, frame in self.core.forwards_to_send(self.channel)
                   if sender is None]
        streams = []
        for frame in frames:
            if _message_id(frame) not in DEFERRED_IDS:
                streams.append(frame)
            elif self._backlog_bytes + len(frame) > BACKLOG_BYTES:
                self.counters["tx_dropped_frames"] += 1
            else:
                self._backlog[_message_id(frame) == PARAM_VALUE].append(frame)
                self._backlog_bytes += len(frame)
        self._refill()
        urgent, params = self._backlog
        self._flush(urgent, lambda n: n <= self._budget)
        self._flush(params, lambda n: n <= min(self._budget, self._param_budget))
        for frame in streams:  # after what waits; skipped when the line is full
            if urgent or len(frame) > self._budget or not self._write(frame):
                self.counters["tx_dropped_frames"] += 1

    def _flush(self, queue: deque[bytes], fits: Callable[[int], bool]) -> None:
        while queue and fits(len(queue[0])):
            frame = queue.popleft()
            self._backlog_bytes -= len(frame)
            if _message_id(frame) == PARAM_VALUE:
                self._param_budget -= len(frame)
            if not self._write(frame):
                self.counters["tx_dropped_frames"] += 1

    def _write(self, frame: bytes) -> bool:
        try:
            os.write(self._master, frame)
        except OSError:  # nobody reads and the pty is full (EAGAIN), or EIO
            return False
        self._budget -= len(frame)
        self.counters["tx_bytes"] += len(frame)
        return True


def start_serial_vehicle(config: VehicleConfig, *, baud: int = 115200, link: Path | None = None,
                         speedup: float = 1.0,
                         tx_buffer_bytes: int = TX_BUFFER_BYTES) -> PtySerialLink:
    """One vehicle on a new pseudo-terminal, served by the running loop."""
    clock = SimClock(asyncio.get_running_loop(), speedup)
    core = VehicleCore(replace(config, speedup=speedup), now=clock())
    serial = PtySerialLink(core, clock, baud=baud, link=link, tx_buffer_bytes=tx_buffer_bytes)
    serial.start()
    return serial


async def start_serial_and_udp_vehicle(
        config: VehicleConfig, *, baud: int = 115200, link: Path | None = None,
        speedup: float = 1.0, host: str = "127.0.0.1", port: int = 0,
        out: tuple[str, int] | None = None) -> tuple[PtySerialLink, VehicleEndpoint]:
    """One vehicle on two links, as a flight controller with TELEM2 wired to the companion's
    UART and its radio (or USB) to a GCS: a pseudo-terminal and a UDP port, each link with its
    own streams (sitl.vehicle.links)."""
    loop = asyncio.get_running_loop()
    clock = SimClock(loop, speedup)
    core = VehicleCore(replace(config, speedup=speedup), now=clock(), links=("serial", "udp"))
    group = LinkGroup(core, clock)
    serial = PtySerialLink(core, clock, baud=baud, link=link, channel="serial", group=group)
    protocol = VehicleProtocol(core, clock, out=out, link="udp", group=group)
    try:
        transport, _ = await loop.create_datagram_endpoint(lambda: protocol,
                                                           local_addr=(host, port))
    except BaseException:
        serial.close()
        raise
    sock = transport.get_extra_info("sockname")
    serial.start()
    return serial, VehicleEndpoint(core=core, protocol=protocol, transport=transport,
                                   address=(str(sock[0]), int(sock[1])))
