"""Opening the autopilot link with pymavlink, and the fixes its UDP and TCP links need."""

from __future__ import annotations

import errno
from collections.abc import Callable
from typing import Any

from companion.mavlink_commands import MavlinkSettings

__all__ = ["default_connect"]


def default_connect(settings: MavlinkSettings) -> Any:
    from pymavlink import mavutil

    # retries=0: one connect attempt; the thread retries every reconnect_delay_s (pymavlink's
    # default blocks 3 s per attempt and prints "... sleeping" each second).
    conn = mavutil.mavlink_connection(
        settings.url, baud=settings.baud, source_system=settings.source_system,
        source_component=settings.source_component, autoreconnect=False, retries=0,
    )
    if isinstance(conn, mavutil.mavtcp):
        # The peer closed the connection (ArduPilot SITL rebooting, mavlink-router restarting):
        # pymavlink would print "EOF on TCP socket" on every read and spin until the
        # heartbeat timeout; raise instead, so the link is lost (and reopened) at once.
        conn.handle_eof = conn.handle_disconnect = _tcp_closed
    elif isinstance(conn, mavutil.mavudp):
        conn.recv = _datagram_at_a_time(conn.recv, conn.mav)
    return conn


def _datagram_at_a_time(recv: Callable[..., Any], parser: Any) -> Callable[..., Any]:
    """``recv`` that drops what is left of a torn frame before a new datagram is parsed.

    MAVLink over UDP sends whole frames per datagram, but pymavlink's parser is one stream
    for every sender: 10 bytes from anyone promising a 255-byte frame took the autopilot's
    next datagram as that frame's payload, and a sender doing it before each HEARTBEAT kept
    the companion from ever seeing its autopilot (docs/security.md, 2026-11-24). Complete
    frames still waiting in the buffer are kept. Uses the parser's ``buf``/``buf_index``/
    ``expected_length`` (pymavlink's generated ``MAVLink`` class)."""
    def recv_datagram(n: int | None = None) -> Any:
        data = recv(n)
        if data and parser.buf_len() > 0 and parser.expected_length > parser.buf_len():
            parser.buf = bytearray()
            parser.buf_index = 0
            parser.expected_length = _HEADER_LEN_V1 + 2
        return data

    return recv_datagram


_HEADER_LEN_V1 = 6
"""What pymavlink's parser expects first (``HEADER_LEN_V1 + 2``, as its ``__init__`` sets)."""


def _tcp_closed() -> None:
    raise ConnectionResetError(errno.ECONNRESET, "the autopilot closed the TCP connection")

