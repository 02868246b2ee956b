"""The ground station's transport seam: how datagrams reach :class:`GroundLink` and leave it.

The link (``ground_station.receiver``) is protocol logic: it feeds the sans-I/O decoder,
reports and commands. It never touches a socket; a transport does, and the address type is
the transport's own (UDP: ``(host, port)``; a peer-to-peer or radio transport brings its
own). The link treats addresses as opaque, hashable values it got from the transport and
gives back to it, the way the drone's ``companion.transport`` serves the companion.

:class:`UdpTransport` is the one implementation today: a non-blocking socket read by a
reader callback that drains every queued datagram per wake-up (one loop iteration per
burst, not per datagram), with the largest kernel receive buffer the host grants.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
import sys
from collections import Counter
from collections.abc import Hashable, Sequence
from typing import TYPE_CHECKING, Protocol, TypeVar

if TYPE_CHECKING:
    from ground_station.config import GroundConfig

__all__ = [
    "DatagramSink",
    "GroundTransport",
    "UdpAddress",
    "UdpTransport",
    "set_receive_buffer",
    "udp_transport",
]

log = logging.getLogger(__name__)

A = TypeVar("A", bound=Hashable)
A_contra = TypeVar("A_contra", bound=Hashable, contravariant=True)

UdpAddress = tuple[str, int]
"""A UDP peer: (IPv4 host, port)."""

MAX_READS_PER_WAKEUP = 512
"""Datagrams read per wake-up before the loop serves others (timers, HTTP, WebSocket)."""
RECV_BYTES = 2048
"""Larger than any valid datagram (1200 bytes), so oversize ones are seen and counted."""


class DatagramSink(Protocol[A_contra]):
    """What a transport delivers to: the link's protocol logic."""

    def datagrams_received(self, datagrams: Sequence[tuple[bytes, A_contra]]) -> None:
        """A burst of datagrams that arrived together, each with its sender's address."""


class GroundTransport(Protocol[A]):
    """A datagram transport the ground station's link speaks the fleet protocol over.

    ``send`` never blocks and never raises for the link: a datagram it cannot send (full
    buffer, unreachable peer) is counted in :attr:`counters` and lost like on the air.
    """

    counters: Counter[str]

    async def open(self, sink: DatagramSink[A]) -> A:
        """Start delivering to ``sink``; returns the local address."""

    def send(self, datagram: bytes, addr: A) -> bool:
        """Send one datagram; False when it was dropped (and counted)."""

    def close(self) -> None:
        """Stop receiving and release the transport; idempotent."""

    @property
    def local_addr(self) -> A:
        """Where the fleet reaches this station (valid once open)."""

    def stats(self) -> dict[str, int]:
        """Transport facts for ``/api/stats`` (e.g. the receive buffer granted)."""


class UdpTransport:
    """One UDP socket bound to ``(host, port)``; implements :class:`GroundTransport`."""

    def __init__(self, host: str, port: int, *, rcvbuf_bytes: int,
                 medium: str | None = None) -> None:
        self.host = host
        self.port = port
        self.medium = medium
        """Also hear the fleet's shared medium (``broadcast:``/``multicast:``, docs/peers.md)."""
        self._medium_sock: socket.socket | None = None
        self.rcvbuf_bytes = rcvbuf_bytes
        """Asked for; :meth:`stats` says what the kernel granted."""
        self.granted_rcvbuf_bytes = 0
        self.counters: Counter[str] = Counter()
        self._sock: socket.socket | None = None
        self._sink: DatagramSink[UdpAddress] | None = None

    async def open(self, sink: DatagramSink[UdpAddress]) -> UdpAddress:
        loop = asyncio.get_running_loop()
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            # No SO_REUSEADDR: on a UDP socket it lets a second station bind the same port
            # and silently take the fleet's datagrams from the first; UDP has no TIME_WAIT.
            self.granted_rcvbuf_bytes = set_receive_buffer(sock, self.rcvbuf_bytes)
            try:
                sock.bind((self.host, self.port))
            except OSError as exc:
                raise OSError(exc.errno, f"UDP {self.host}:{self.port}: {exc.strerror}"
                              ) from None
            sock.setblocking(False)
        except BaseException:
            sock.close()
            raise
        self._sock, self._sink = sock, sink
        loop.add_reader(sock.fileno(), self._read_ready, sock)
        if self.medium is not None:
            from companion.medium import medium_problem, open_medium_socket, parse_medium

            medium = parse_medium(self.medium)
            try:
                medium_sock = open_medium_socket(medium)
            except OSError as exc:  # "cannot serve: [Errno 19] No such device" named nothing
                self.close()
                raise OSError(exc.errno, medium_problem(exc, medium, "shared_medium")
                              ) from None
            except BaseException:
                self.close()
                raise
            self._medium_sock = medium_sock
            loop.add_reader(medium_sock.fileno(), self._read_ready, medium_sock)
            log.info("listening to the shared medium %s", self.medium)
        return self.local_addr

    @property
    def local_addr(self) -> UdpAddress:
        if self._sock is None:
            raise RuntimeError("UDP transport not open")
        host, port = self._sock.getsockname()[:2]
        return str(host), int(port)

    def close(self) -> None:
        for sock in (self._sock, self._medium_sock):
            if sock is None:
                continue
            with contextlib.suppress(RuntimeError):  # no running loop (at interpreter exit)
                asyncio.get_running_loop().remove_reader(sock.fileno())
            sock.close()
        self._sock = self._medium_sock = None

    def _read_ready(self, sock: socket.socket) -> None:
        sink = self._sink
        if sink is None or sock.fileno() < 0:
            return
        recvfrom = sock.recvfrom
        burst: list[tuple[bytes, UdpAddress]] = []
        for _ in range(MAX_READS_PER_WAKEUP):
            try:
                burst.append(recvfrom(RECV_BYTES))
            except (BlockingIOError, InterruptedError):
                break
            except OSError as exc:
                # ICMP port unreachable from a drone that went away: count, keep reading.
                self.counters["socket_errors"] += 1
                log.debug("UDP socket error: %s", exc)
        if burst:
            sink.datagrams_received(burst)

    def send(self, datagram: bytes, addr: UdpAddress) -> bool:
        if self._sock is None:
            self.counters["send_not_open"] += 1
            return False
        try:
            self._sock.sendto(datagram, addr)
        except (BlockingIOError, InterruptedError):
            # Best effort (ARCHITECTURE.md): a full send buffer drops, never blocks the loop.
            self.counters["send_dropped"] += 1
            return False
        except OSError as exc:
            self.counters["send_errors"] += 1
            log.debug("UDP send to %s failed: %s", addr, exc)
            return False
        self.counters["datagrams_sent"] += 1
        return True

    def stats(self) -> dict[str, int]:
        return {"udp_rcvbuf_bytes": self.granted_rcvbuf_bytes}


def udp_transport(config: GroundConfig) -> UdpTransport:
    """The UDP transport a ground-station config asks for."""
    return UdpTransport(config.udp_host, config.udp_port, rcvbuf_bytes=config.udp_rcvbuf_bytes,
                        medium=config.shared_medium)


def set_receive_buffer(sock: socket.socket, size: int) -> int:
    """Ask for a large kernel receive buffer so bursts of fragments are not lost in the
    kernel while the loop is busy. SO_RCVBUFFORCE (Linux, with CAP_NET_ADMIN) may exceed
    net.core.rmem_max; otherwise SO_RCVBUF is capped by it. Returns what the kernel granted.
    """
    force = getattr(socket, "SO_RCVBUFFORCE", 33 if sys.platform.startswith("linux") else None)
    granted_before = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
    if force is not None:
        try:
            sock.setsockopt(socket.SOL_SOCKET, force, size)
        except OSError:
            force = None
    if force is None:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, size)
    granted = int(sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF))
    if granted < min(size, 2 * granted_before):  # pragma: no cover - depends on the host
        log.warning("UDP receive buffer is %d bytes (asked %d)", granted, size)
    return granted
