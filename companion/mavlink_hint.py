"""Why an opened MAVLink link stays silent: said by `uav-companion check` and in `run`'s log.

A program bound to 127.0.0.1:P with SO_REUSEADDR (as every pymavlink one is) gets what the
autopilot sends to 127.0.0.1:P, and a companion's udpin on the same port binds all the same:
the link opens and hears nothing.
"""

from __future__ import annotations

import os
import socket
from pathlib import Path

__all__ = ["other_openers", "sharing_hint", "silence_hint", "udp_listeners"]


UNPARSABLE_MIN = 3
"""Unparsable chunks that make a silent line a baud problem: a wrong baud rate brings them
steadily, while a frame torn by a reboot or a pulled cable is one (ArduCopter 4.5 SITL sent
6 unparsable bytes on its UART 1.2 s after MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, measured)."""


def silence_hint(url: str, *, own_socket_open: bool = False, unparsable: int = 0,
                 baud: int | None = None) -> str:
    """What usually explains an open link that stays silent. ``own_socket_open``: our socket
    is still bound (``run``'s log), so one listener at our address is ours; `check` asks
    after closing it, so every listener is another program, also one at our very address
    (the default ``udpin:127.0.0.1:14550`` and another companion's). ``unparsable``: bytes
    came that made no MAVLink frame (pymavlink's BAD_DATA), on a serial line the sign of a
    baud rate that differs from the autopilot's, or of a port set to another protocol."""
    scheme, _, rest = url.partition(":")
    if scheme == "udpin":
        host, _, port = rest.rpartition(":")
        others = udp_listeners(int(port)) if port.isdigit() else []
        ours = f"{_ipv4(host)}:{port}"
        if own_socket_open and ours in others:
            others.remove(ours)
        if others:  # pymavlink binds with SO_REUSEADDR: it shares the port, silently
            where = ", ".join(sorted(set(others)))
            return (f"another program also listens on {where} and gets the "
                    f"datagrams sent there: stop it (mavlink-router, MAVProxy, another "
                    f"companion?) or pick another port")
        return (f"nothing sent MAVLink to {rest}: point the autopilot's telemetry output, "
                f"mavlink-router or the SITL's --out at this port")
    if scheme in ("udpout", "udp", "tcp"):
        return f"nothing answered at {rest}: is the autopilot or SITL running there?"
    shared = sharing_hint(url)
    if shared is not None:
        return shared
    if unparsable >= UNPARSABLE_MIN:
        rate = url.partition(",")[2] or baud or "the configured rate"
        return (f"bytes arrive but no MAVLink frame parses ({unparsable} unparsable): the baud "
                f"rate ({rate}) differs from the autopilot's (SERIALn_BAUD on ArduPilot, "
                "SER_TELn_BAUD on PX4), or the port speaks another protocol (SERIALn_PROTOCOL "
                "2 = MAVLink 2)")
    return ("the line is open but silent: check the wiring (TX to RX, a common ground), the "
            "baud rate and SERIALn_PROTOCOL")


def sharing_hint(url: str) -> str | None:
    """For a serial URL that another process also has open: what goes wrong and what to do.

    Two programs reading one UART (MAVProxy or a GCS bridge started on /dev/serial0 beside
    the companion) each get part of its bytes: both lose frames, and pyserial's read fails
    with "device reports readiness to read but returned no data", so the companion lost its
    link 3 times in 30 s (measured on a pty with a second pyserial reader)."""
    device = url.split(",")[0]
    if not device.startswith("/"):
        return None
    others = other_openers(device)
    if not others:
        return None
    return (f"another program also has {device} open ({', '.join(others)}): two programs "
            "reading one serial port each get part of its bytes, and both lose frames and "
            "the link; give the companion its own output instead (mavlink-router or MAVProxy "
            "--out udp:127.0.0.1:14550 with url = \"udpin:127.0.0.1:14550\") or its own "
            "TELEM port")


def other_openers(device: str) -> list[str]:
    """``PID (NAME)`` of the other processes that have ``device`` open (Linux ``/proc``;
    another user's processes are visible to root only)."""
    target = os.path.realpath(device)
    found = []
    try:
        pids = [p for p in Path("/proc").iterdir() if p.name.isdigit()]
    except OSError:  # not Linux: no hint
        return []
    for pid in pids:
        if int(pid.name) == os.getpid():
            continue
        try:
            links = {os.readlink(fd) for fd in (pid / "fd").iterdir()}
            # A pseudo-terminal's provider (socat, the simulated vehicle) holds its master,
            # /dev/ptmx: the other end of the wire, not a second reader of this end.
            if target in links and "/dev/ptmx" not in links:
                name = (pid / "comm").read_text().strip()
                found.append(f"pid {pid.name}: {name}")
        except OSError:  # gone, or not ours to read
            continue
    return sorted(found)


def _ipv4(host: str) -> str:
    """``localhost`` as /proc/net/udp lists it (a name that does not resolve: as given)."""
    try:
        return socket.gethostbyname(host)
    except (OSError, UnicodeError):
        return host


def udp_listeners(port: int) -> list[str]:
    """IPv4 ``HOST:PORT``s bound to ``port`` on this machine (Linux ``/proc/net/udp``), one
    entry per socket: a program bound to 127.0.0.1:14550 takes the autopilot's datagrams
    from our 0.0.0.0:14550 (or our 127.0.0.1:14550), and both binds succeed (SO_REUSEADDR)."""
    try:
        lines = Path("/proc/net/udp").read_text().splitlines()[1:]
    except OSError:  # not Linux: no hint
        return []
    found = []
    for line in lines:
        local = line.split()[1] if len(line.split()) > 1 else ""
        host_hex, _, port_hex = local.partition(":")
        if len(host_hex) == 8 and port_hex and int(port_hex, 16) == port:
            host = ".".join(str(b) for b in reversed(bytes.fromhex(host_hex)))
            found.append(f"{host}:{port}")
    return sorted(found)
