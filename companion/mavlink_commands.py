"""What the companion asks of the autopilot: commands, link settings, and error wording.

Shared by the reader thread (:mod:`companion.mavlink_reader`) and its asyncio face
(:class:`companion.mavlink.MavlinkService`).
"""


from __future__ import annotations

import concurrent.futures
import errno
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from companion.mavlink_convert import (
    MAV_CMD_COMPONENT_ARM_DISARM,
    MAV_CMD_DO_SET_MODE,
    MAV_COMP_ID_ONBOARD_COMPUTER,
)

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



class CommandError(Exception):
    """A command the vehicle did not carry out; the text says which and why."""




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


DEFAULT_MAVLINK_URL = "udpin:127.0.0.1:14550"
"""Loopback, like the ground station's ports: MAVLink here is unsigned, and pymavlink's
``udpin`` (2.4.50) sends what the companion writes to every address it has heard from. On
``0.0.0.0`` (the default before 2026-11-24) any host
on the drone's networks, the radio link among them, could speak for the autopilot (its
HEARTBEAT and positions taken as the vehicle's) and take the companion's stream requests,
commands and ADSB_VEHICLE reports of its peers away from the real one."""


def wildcard_mavlink_warning(url: str) -> str | None:
    """The warning for a ``udpin``/``udp`` URL that listens on every interface, else None."""
    scheme, _, rest = url.partition(":")
    host = rest.rpartition(":")[0].strip("[]")
    if scheme not in ("udpin", "udp") or host not in ("0.0.0.0", "::", ""):
        return None
    return (f"mavlink.url {url} listens on every network interface: any host that reaches "
            "this port speaks for the autopilot (MAVLink is unsigned) and gets what the "
            "companion sends it; use the address the autopilot sends to (127.0.0.1 for "
            "mavlink-router or a SITL on this computer)")


@dataclass(frozen=True, slots=True, kw_only=True)
class MavlinkSettings:
    url: str
    """pymavlink connection string: ``udpin:127.0.0.1:14550``, ``tcp:host:5760``,
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





def command_id(command: Command) -> int | None:
    if isinstance(command, SetModeCommand):
        return MAV_CMD_DO_SET_MODE
    if isinstance(command, ArmCommand):
        return MAV_CMD_COMPONENT_ARM_DISARM
    return None


def describe_command(command: Command) -> str:
    if isinstance(command, SetModeCommand):
        return f"set mode {command.mode}"
    if isinstance(command, ArmCommand):
        return "arm" if command.arm else "disarm"
    if isinstance(command, ParamReadCommand):
        return f"read parameter {command.name}"
    return type(command).__name__


def unconfirmed(command: Command) -> str:
    """Why ``command`` failed when nothing answered it in time."""
    if isinstance(command, ParamReadCommand):  # ArduCopter 4.5 SITL: no answer, measured
        return (f"read parameter {command.name}: no PARAM_VALUE within {command.timeout_s} s "
                "(the autopilot has no such parameter: it answers an unknown name with nothing)")
    return f"{describe_command(command)}: not confirmed by HEARTBEAT within {command.timeout_s} s"


def fail_command(command: Command, text: str) -> None:
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

