"""The companion's read-only ``GET /peers`` endpoint (docs/peers.md), a thin shell on asyncio
streams around :class:`~companion.peer_table.PeerTable`.

No client holds it forever: a request must arrive within ``READ_TIMEOUT_S``, its reply must be
taken within ``send_timeout_s`` (a client that stops reading is dropped, not waited for), and
at most ``max_per_address`` connections from one address, ``max_connections`` in all, are
open at once (more are closed on accept, like a full listen queue).
"""

from __future__ import annotations

import asyncio
import ipaddress
import json
import logging
import math
from collections.abc import Callable
from typing import Any

from companion.admission import ConnectionGate
from companion.peer_table import PeerTable

__all__ = ["MAX_CONNECTIONS", "MAX_PER_ADDRESS", "SEND_TIMEOUT_S", "PeerHttp"]

log = logging.getLogger("companion.peers")  # one logger name for the peer services

MAX_CONNECTIONS = 32
"""Default ``peers.http_max_connections``: connections open at once, all addresses."""
MAX_PER_ADDRESS = 8
"""Default ``peers.http_max_per_address``: connections open at once from one address."""
SEND_TIMEOUT_S = 5.0
"""Default ``peers.http_send_timeout_s``: a reply not taken by then drops the client."""
WARN_EVERY_S = 60.0
"""Refusals and drops are logged once, then at most once a minute with a count."""

_REASONS = {200: "OK", 400: "Bad Request", 404: "Not Found", 405: "Method Not Allowed",
            421: "Misdirected Request"}


def _local_host(host: str) -> bool:
    """A ``Host`` value naming an IP literal or localhost (with or without a port)."""
    name = host.strip()
    if name.startswith("["):  # [v6] or [v6]:port
        name = name[1:name.find("]")] if "]" in name else name
    elif name.count(":") == 1:  # name:port or v4:port
        name = name.rsplit(":", 1)[0]
    if name.lower().rstrip(".") == "localhost":
        return True
    try:
        ipaddress.ip_address(name.split("%", 1)[0])
    except ValueError:
        return False
    return True


class PeerHttp:
    """Read-only local JSON: ``GET /peers`` and ``GET /peers/<drone>``; nothing else.

    A deliberately small HTTP/1.0 responder on asyncio streams (no framework on the drone's
    hot path): one request per connection, bounded request size and read time, bounded reply
    time and connections, and only GET. Bind it to 127.0.0.1 (the default in docs/peers.md):
    it has no authentication.
    """

    MAX_REQUEST_BYTES = 4096
    READ_TIMEOUT_S = 5.0

    def __init__(self, table: PeerTable, *, clock: Callable[[], float], host: str,
                 port: int, max_connections: int = MAX_CONNECTIONS,
                 max_per_address: int = MAX_PER_ADDRESS,
                 send_timeout_s: float = SEND_TIMEOUT_S) -> None:
        self.table = table
        self.clock = clock
        self.host = host
        self.port = port
        self.send_timeout_s = send_timeout_s
        self.server: asyncio.Server | None = None
        self.gate = ConnectionGate(max_total=max_connections, max_per_client=max_per_address)
        self.counters: dict[str, int] = {"refused": 0, "dropped": 0}
        self._warned: dict[str, tuple[float, int]] = {}

    async def start(self) -> tuple[str, int]:
        self.server = await asyncio.start_server(self._accept, self.host, self.port,
                                                 limit=self.MAX_REQUEST_BYTES)
        sock = self.server.sockets[0].getsockname()
        log.info("peer state on http://%s:%d/peers", sock[0], sock[1])
        return str(sock[0]), int(sock[1])

    def close(self) -> None:
        if self.server is not None:
            self.server.close()
            self.server = None

    async def _accept(self, reader: asyncio.StreamReader,
                      writer: asyncio.StreamWriter) -> None:
        peer = writer.get_extra_info("peername")
        address = str(peer[0]) if peer else "?"
        refused = self.gate.admit(address)
        if refused is not None:
            self.counters["refused"] += 1
            self._warn("refused", f"connection from {address} refused: at most "
                       f"{self.gate.max_per_client} per address and {self.gate.max_total} "
                       "in all (peers.http_max_per_address, peers.http_max_connections)")
            writer.transport.abort()
            return
        try:
            await self._serve(reader, writer, address)
        finally:
            self.gate.release(address)

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter,
                     address: str) -> None:
        try:
            async with asyncio.timeout(self.READ_TIMEOUT_S):
                head = await reader.readuntil(b"\r\n\r\n")
            line, *fields = head.decode("latin-1").split("\r\n")
            hosts = [v for k, _, v in (f.partition(":") for f in fields)
                     if k.strip().lower() == "host"]
            status, body = self.respond(line.encode("latin-1"),
                                        host=hosts[0].strip() if hosts else None)
        except (asyncio.IncompleteReadError, asyncio.LimitOverrunError, TimeoutError,
                ConnectionError):
            status, body = 400, {"error": "bad request"}
        payload = json.dumps(body).encode()
        try:
            writer.write(f"HTTP/1.0 {status} {_REASONS[status]}\r\n"
                         f"Content-Type: application/json\r\nContent-Length: {len(payload)}"
                         "\r\nCache-Control: no-store\r\nConnection: close\r\n\r\n".encode()
                         + payload)
            # until the last byte has left: close() alone would keep a transport with
            # unsent data (and its connection slot) for as long as the client does not read
            async with asyncio.timeout(self.send_timeout_s):
                await writer.drain()
                writer.close()
                await writer.wait_closed()
        except TimeoutError:
            self.counters["dropped"] += 1
            self._warn("dropped", f"{address} did not take its reply within "
                       f"{self.send_timeout_s:g} s: dropped (peers.http_send_timeout_s)")
        except ConnectionError:
            pass
        finally:
            writer.transport.abort()  # a no-op once closed; frees the socket otherwise

    def _warn(self, kind: str, text: str) -> None:
        """Once, then at most every WARN_EVERY_S with how many since: a flood of
        connections must not become a flood of log lines."""
        now = self.clock()
        last, since = self._warned.get(kind, (-math.inf, 0))
        if now - last < WARN_EVERY_S:
            self._warned[kind] = (last, since + 1)
            return
        more = f" ({since} more since the last warning)" if since else ""
        log.warning("peers.http: %s%s", text, more)
        self._warned[kind] = (now, 0)

    def respond(self, request_line: bytes, host: str | None = None
                ) -> tuple[int, dict[str, Any]]:
        """Status and JSON body for one request line and its ``Host`` header (sans-I/O,
        tested directly). Only IP literals and ``localhost`` are served: a page on
        ``evil.example`` rebound to 127.0.0.1 sends ``Host: evil.example`` and, the
        endpoint having no token, could otherwise read every peer's position."""
        parts = request_line.decode("latin-1").split(" ")
        if len(parts) != 3 or not parts[2].startswith("HTTP/"):
            return 400, {"error": "bad request"}
        if host is not None and not _local_host(host):
            return 421, {"error": "Host must be an IP address or localhost "
                                  "(DNS rebinding protection)"}
        method, path = parts[0], parts[1].split("?", 1)[0]
        if method != "GET":
            return 405, {"error": "read-only: GET only"}
        now = self.clock()
        if path in ("/peers", "/peers/"):
            return 200, self.table.snapshot(now)
        if path.startswith("/peers/"):
            peer = self.table.peers.get(path[len("/peers/"):])
            if peer is not None:
                return 200, peer.to_json(now)
        return 404, {"error": "not found"}
