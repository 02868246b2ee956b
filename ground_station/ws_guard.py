"""Bounds on the dashboard's WebSockets, so idle or non-reading clients cannot starve HTTP.

A WebSocket holds one of the ``http_max_connections`` connections for as long as it is open
(the idle timeout does not apply to it). :class:`WebSocketGate` admits at most
``max_per_client`` per client address and ``max_total`` in all (half the HTTP connections),
so plain requests always have connections left. :func:`send_or_drop` bounds how long one
update may wait for the socket: a client that stops reading is dropped by aborting its
connection (a plain close waits for unsent data to drain, which never happens).
"""

from __future__ import annotations

import asyncio
import logging
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass, field

from aiohttp import WSCloseCode, web

__all__ = ["WebSocketGate", "abort", "close_all", "refusal", "release_unsent", "send_or_drop"]

log = logging.getLogger(__name__)


@dataclass
class WebSocketGate:
    """Counts open WebSockets per client address; sans-I/O."""

    max_total: int
    max_per_client: int
    open_by_client: Counter[str] = field(default_factory=Counter)
    refused: int = 0

    @classmethod
    def for_connections(cls, http_max_connections: int, max_per_client: int) -> WebSocketGate:
        """WebSockets may take at most half the HTTP connections (at least one)."""
        return cls(max_total=max(1, http_max_connections // 2), max_per_client=max_per_client)

    @property
    def open(self) -> int:
        return sum(self.open_by_client.values())

    def admit(self, client: str) -> tuple[int, str] | None:
        """None (and the client counted) or why not: (HTTP status, one line)."""
        if self.open_by_client[client] >= self.max_per_client:
            self.refused += 1
            return 429, (f"WebSocket refused: {client} has {self.max_per_client} open "
                         f"(ws_max_per_client)")
        if self.open >= self.max_total:
            self.refused += 1
            return 503, (f"WebSocket refused: {self.max_total} open (half of "
                         f"http_max_connections); {client} must wait")
        self.open_by_client[client] += 1
        return None

    def release(self, client: str) -> None:
        self.open_by_client[client] -= 1
        if self.open_by_client[client] <= 0:
            del self.open_by_client[client]

    def should_log(self) -> bool:
        """Log the 1st, 10th, 100th... refusal, not every one (a loop must not flood)."""
        return self.refused in (1, 10, 100) or self.refused % 1000 == 0


def refusal(status: int, text: str) -> web.HTTPException:
    """The refusal reply; its connection closes (an idle kept-alive one holds a slot)."""
    cls = web.HTTPTooManyRequests if status == 429 else web.HTTPServiceUnavailable
    response = cls(text=text + "\n", headers={"Retry-After": "10"})
    response.force_close()
    return response


def abort(request: web.BaseRequest) -> None:
    """Drop the connection now, with whatever it still had to send."""
    transport = request.transport
    if transport is not None:
        transport.abort()


def release_unsent(request: web.BaseRequest) -> None:
    """At a WebSocket's end: a connection that still has unsent data is aborted. aiohttp's
    heartbeat "closes" an unresponsive client's transport, which then waits for that data
    to drain: for a client that does not read, forever."""
    transport = request.transport
    if transport is not None and transport.get_write_buffer_size():
        transport.abort()


async def send_or_drop(request: web.BaseRequest, ws: web.WebSocketResponse, text: str, *,
                       timeout_s: float) -> bool:
    """Send ``text``; False (and the client dropped) when it cannot go out in time."""
    try:
        async with asyncio.timeout(timeout_s):
            await ws.send_str(text)
    except TimeoutError:
        log.warning("WebSocket client %s dropped: an update could not be sent in %g s "
                    "(not reading)", request.remote, timeout_s)
        abort(request)
        return False
    return True


async def close_all(feeds: Mapping[web.WebSocketResponse, web.BaseRequest], *,
                    timeout_s: float) -> None:
    """Close every live feed at shutdown, all at once; one that cannot take the close frame
    or does not answer it within ``timeout_s`` is aborted: a stop never waits on a client
    (one that did not read held Ctrl-C forever)."""

    async def close(ws: web.WebSocketResponse, request: web.BaseRequest) -> None:
        try:
            async with asyncio.timeout(timeout_s):
                await ws.close(code=WSCloseCode.GOING_AWAY, message=b"server shutdown")
        except TimeoutError:
            abort(request)

    await asyncio.gather(*(close(ws, request) for ws, request in list(feeds.items())))
