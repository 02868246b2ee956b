"""Bounds on the dashboard's WebSockets, so idle or non-reading clients cannot starve HTTP.

A WebSocket holds one of the ``http_max_connections`` connections for as long as it is open
(the idle timeout does not apply to it). :func:`websocket_gate` admits at most
``max_per_client`` per client address and ``max_total`` in all (half the HTTP connections),
so plain requests always have connections left. :func:`send_or_drop` bounds how long one
update may wait for the socket: a client that stops reading is dropped by aborting its
connection (a plain close waits for unsent data to drain, which never happens).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Mapping

from aiohttp import WSCloseCode, web

from companion.admission import ConnectionGate, Refusal

__all__ = ["abort", "close_all", "refusal", "refusal_text", "release_unsent", "send_or_drop",
           "websocket_gate"]

log = logging.getLogger(__name__)


def websocket_gate(http_max_connections: int, max_per_client: int) -> ConnectionGate:
    """WebSockets may take at most half the HTTP connections (at least one)."""
    return ConnectionGate(max_total=max(1, http_max_connections // 2),
                          max_per_client=max_per_client)


def refusal_text(refused: Refusal) -> str:
    if refused.reason == "client":
        return (f"WebSocket refused: {refused.client} has {refused.cap} open "
                "(ws_max_per_client)")
    return (f"WebSocket refused: {refused.cap} open (half of http_max_connections); "
            f"{refused.client} must wait")


def refusal(refused: Refusal) -> web.HTTPException:
    """The refusal reply (429: this client holds its share; 503: all are taken); its
    connection closes (an idle kept-alive one holds a slot)."""
    cls = web.HTTPTooManyRequests if refused.reason == "client" else web.HTTPServiceUnavailable
    response = cls(text=refusal_text(refused) + "\n", headers={"Retry-After": "10"})
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
