"""The shared medium: one datagram to every fleet member by UDP broadcast or multicast
(docs/peers.md). Parsing its ``broadcast:``/``multicast:`` address and opening its sockets;
the drone's :class:`~companion.transport.UdpTransport` and the ground station both use it.
"""

from __future__ import annotations

import errno
import ipaddress
import socket
from dataclasses import dataclass
from typing import Literal

__all__ = ["SharedMedium", "medium_problem", "open_medium_socket", "parse_medium",
           "prepare_medium_sender", "sender_id"]


@dataclass(frozen=True, slots=True, kw_only=True)
class SharedMedium:
    """One datagram to every fleet member: UDP broadcast or multicast (docs/peers.md).

    Every member (drones and the ground station) listens on ``port`` of this address;
    datagrams are still sent from each member's own unicast socket, so replies (reports,
    commands) go back to the sender's address as before.
    """

    kind: Literal["broadcast", "multicast"]
    address: str
    port: int
    interface: str = "0.0.0.0"
    """Local address of the interface multicast is sent and joined on (127.0.0.1 on one
    machine, the radio's address in the field)."""

    @property
    def target(self) -> tuple[str, int]:
        return (self.address, self.port)

    def __str__(self) -> str:
        """As configured: ``broadcast:ADDR:PORT`` or ``multicast:GROUP:PORT:IFACE_ADDR``."""
        tail = f":{self.interface}" if self.interface != "0.0.0.0" else ""
        return f"{self.kind}:{self.address}:{self.port}{tail}"


def medium_problem(exc: OSError, medium: SharedMedium, setting: str) -> str:
    """One line for a medium whose sockets cannot be opened: the setting, what the system
    said and what to change (the bare ``OSError(99, 'Cannot assign requested address')``
    named neither the medium nor the fix)."""
    said = exc.strerror or str(exc)
    if exc.errno == errno.EADDRINUSE:
        hint = (f"port {medium.port} is held by a program that does not share it (the "
                "ground station's udp_port on this computer?): give every fleet member the "
                "same medium port, one no other socket uses")
    elif medium.kind == "multicast" and medium.interface != "0.0.0.0" \
            and exc.errno in (errno.EADDRNOTAVAIL, errno.ENODEV):
        hint = (f"{medium.interface} is not an address of this computer: the fourth part is "
                "this member's own address on the fleet network")
    elif medium.kind == "multicast" and exc.errno in (errno.ENODEV, errno.EADDRNOTAVAIL):
        hint = ("no interface to join the group on: add this member's own address on the "
                f"fleet network ({setting} = \"multicast:{medium.address}:{medium.port}:"
                "IFACE_ADDR\")")
    else:
        hint = f"check {setting} (docs/peers.md)"
    return f"{setting} {medium}: cannot open the shared medium ({said}): {hint}"


def parse_medium(text: str) -> SharedMedium:
    """``broadcast:ADDR:PORT`` or ``multicast:GROUP:PORT[:IFACE_ADDR]``; ValueError (one
    line) otherwise."""
    parts = text.split(":")
    usage = (f"expected broadcast:ADDR:PORT or multicast:GROUP:PORT[:IFACE_ADDR], "
             f"got {text!r}")
    if len(parts) not in (3, 4) or parts[0] not in ("broadcast", "multicast"):
        raise ValueError(usage)
    if len(parts) == 4 and parts[0] != "multicast":
        raise ValueError(usage)
    try:
        address = ipaddress.IPv4Address(parts[1])
        interface = ipaddress.IPv4Address(parts[3]) if len(parts) == 4 else None
    except ValueError:
        raise ValueError(usage) from None
    if not parts[2].isdigit() or not 1 <= int(parts[2]) <= 65535:
        raise ValueError(usage)
    if parts[0] == "multicast" and not address.is_multicast:
        raise ValueError(f"{parts[1]} is not a multicast group (224.0.0.0/4)")
    kind: Literal["broadcast", "multicast"] = "broadcast" if parts[0] == "broadcast" \
        else "multicast"
    return SharedMedium(kind=kind, address=str(address), port=int(parts[2]),
                        interface=str(interface) if interface is not None else "0.0.0.0")


def open_medium_socket(medium: SharedMedium) -> socket.socket:
    """A non-blocking socket receiving the medium's datagrams; several processes on one
    host may hold one each (SO_REUSEADDR: broadcast and multicast reach all of them)."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        if medium.kind == "multicast":
            sock.bind((medium.address, medium.port))
            mreq = socket.inet_aton(medium.address) + socket.inet_aton(medium.interface)
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, mreq)
        else:
            sock.bind(("", medium.port))
        sock.setblocking(False)
    except OSError:
        sock.close()
        raise
    return sock


def prepare_medium_sender(sock: socket.socket, medium: SharedMedium) -> None:
    """Let a unicast socket send to the medium (broadcast permission, multicast interface)."""
    if medium.kind == "broadcast":
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
    else:
        sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF,
                        socket.inet_aton(medium.interface))
        sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
        sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)


def sender_id(data: bytes) -> str | None:
    """The header's sender id (docs/protocol.md: length at offset 26, id from 27), unverified:
    used only to skip our own echo before spending a decode on it."""
    if len(data) < 27:
        return None
    n = data[26]
    try:
        return data[27:27 + n].decode()
    except UnicodeDecodeError:
        return None

