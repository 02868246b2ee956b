"""DNS-rebinding protection: the station answers only to the names it is known by.

A page on ``evil.example`` whose DNS record is switched to the station's LAN address is,
to the browser, still ``evil.example``: same-origin with itself, so it may read the
station's replies, and every request it makes carries ``Host: evil.example``. Refusing
DNS names the operator did not allow (HTTP 421) ends that. IP literals (v4, v6, with or
without a port) are accepted, since a rebinding page cannot be served under one, and so is
``localhost``; other names come from ``--allowed-host`` / ``allowed_hosts`` and the
configured ``http_host``.

State-changing requests (anything but GET/HEAD/OPTIONS, and the WebSocket upgrade) that
carry an ``Origin`` must come from this very origin: a browser page elsewhere cannot post
to the API or open the live feed, whatever credentials it has.
"""

from __future__ import annotations

import ipaddress
import logging
from collections.abc import Awaitable, Callable, Iterable

from aiohttp import web
from aiohttp.typedefs import Middleware

from ground_station.http_guard import same_origin

__all__ = ["allowed_names", "host_guard", "host_name", "host_refusal", "normalize_name",
           "origin_guard"]

log = logging.getLogger(__name__)

Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]
_SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})
_ALWAYS = frozenset({"localhost"})


def normalize_name(name: str) -> str:
    """Lower case, without the trailing dot of a fully qualified name."""
    return name.strip().lower().rstrip(".")


def host_name(host: str) -> str:
    """The host part of a ``Host`` header value: ``[::1]:8080`` -> ``::1``,
    ``gs.lan:8080`` -> ``gs.lan``, ``10.0.0.5`` -> ``10.0.0.5``."""
    host = host.strip()
    if host.startswith("["):  # [v6] or [v6]:port
        end = host.find("]")
        return host[1:end] if end > 0 else host
    if host.count(":") == 1:  # name:port or v4:port
        return host.rsplit(":", 1)[0]
    return host  # a name, v4, or a bare v6 literal (several colons)


def _is_ip_literal(name: str) -> bool:
    try:
        ipaddress.ip_address(name.split("%", 1)[0])  # fe80::1%eth0: a scoped v6 address
    except ValueError:
        return False
    return True


def allowed_names(names: Iterable[str]) -> frozenset[str]:
    """The DNS names accepted besides IP literals: ``localhost`` and ``names``."""
    return _ALWAYS | {normalize_name(n) for n in names if n and not _is_ip_literal(n)}


def host_refusal(host: str | None, allowed: frozenset[str]) -> str | None:
    """Why a request with this ``Host`` header is refused (None: it is served). A request
    without one is served: every browser sends it, so it is not a rebinding page."""
    if host is None:
        return None
    name = host_name(host)
    if _is_ip_literal(name) or normalize_name(name) in allowed:
        return None
    shown = name if name.isprintable() and len(name) <= 253 else repr(name[:64])
    return (f"Host {shown!r} is not a name of this ground station (DNS rebinding "
            f"protection); allow it with --allowed-host {shown}")


def _refuser() -> Callable[[type[web.HTTPException], str], web.HTTPException]:
    """The refusal: one clear line in the body, one log line per distinct text (a page
    hammering the station does not fill the log)."""
    logged: set[str] = set()

    def refuse(status: type[web.HTTPException], text: str) -> web.HTTPException:
        if text not in logged and len(logged) < 1000:
            logged.add(text)
            log.warning("HTTP request refused: %s", text)
        return status(text=text + "\n")

    return refuse


def host_guard(names: Iterable[str]) -> Middleware:
    """First middleware: 421 Misdirected Request for a ``Host`` that is not one of
    ``names``, ``localhost`` or an IP literal."""
    allowed = allowed_names(names)
    refuse = _refuser()

    @web.middleware
    async def middleware(request: web.Request, handler: Handler) -> web.StreamResponse:
        problem = host_refusal(request.headers.get("Host"), allowed)
        if problem is not None:
            raise refuse(web.HTTPMisdirectedRequest, problem)
        return await handler(request)

    return middleware


def origin_guard() -> Middleware:
    """After the token check (whose 401 for a cookie from elsewhere stays what callers
    see): 403 for a state-changing request or WebSocket upgrade whose ``Origin`` is another
    site, even with a valid token in a header."""
    refuse = _refuser()

    @web.middleware
    async def middleware(request: web.Request, handler: Handler) -> web.StreamResponse:
        changes_state = (request.method not in _SAFE_METHODS
                         or request.headers.get("Upgrade", "").lower() == "websocket")
        if changes_state and "Origin" in request.headers and not same_origin(request):
            origin = request.headers["Origin"]
            shown = origin if origin.isprintable() and len(origin) <= 300 else repr(origin[:64])
            raise refuse(web.HTTPForbidden,
                         f"cross-origin {request.method} {request.path} refused: Origin "
                         f"{shown} is not this station")
        return await handler(request)

    return middleware
