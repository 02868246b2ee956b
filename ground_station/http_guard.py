"""HTTP hardening of the dashboard server (docs/ground_station.md, "Security").

* security headers on every response (CSP without inline scripts, no framing, nosniff, no
  Referer, ``Cache-Control: no-store`` on data), added in ``on_response_prepare`` so static
  files and errors get them too;
* a same-origin check for cookie-authenticated requests and the WebSocket;
* an access log that never shows a token or login code (request line and Referer), and a
  request aiohttp cannot parse logged as one line, not a traceback quoting its raw bytes,
  and answered with a fixed 400 body (aiohttp's page quotes the bytes it refused);
* a listening site that caps concurrent connections, plus a short idle timeout, so HTTP
  clients can never use up the file descriptors the UDP receiver and storage need;
* the soft open-file limit raised to the hard one at start.
"""

from __future__ import annotations

import asyncio
import json
import logging
import re
import time
from collections.abc import Callable
from typing import Any

from aiohttp import web
from aiohttp.abc import AbstractAccessLogger
from aiohttp.http_exceptions import HttpProcessingError
from aiohttp.web_protocol import RequestHandler

from companion.admission import worth_logging
from companion.stop_signals import STOP_SIGNALS, EarlyStop

__all__ = [
    "MALFORMED_REQUEST_BODY",
    "SECURITY_HEADERS",
    "FixedErrorPages",
    "LimitedSite",
    "RedactingAccessLogger",
    "UnparsableRequestFilter",
    "add_security_headers",
    "cache_policy",
    "json_reply",
    "raise_open_file_limit",
    "redact",
    "same_origin",
    "serve",
]

log = logging.getLogger(__name__)

SECURITY_HEADERS = {
    "Content-Security-Policy": (
        "default-src 'self'; script-src 'self'; style-src 'self' 'unsafe-inline'; "
        "img-src 'self' data:; connect-src 'self'; object-src 'none'; base-uri 'none'; "
        "form-action 'self'; frame-ancestors 'none'"
    ),
    "X-Frame-Options": "DENY",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "Cross-Origin-Resource-Policy": "same-origin",
    "Cross-Origin-Opener-Policy": "same-origin",
}
"""Inline scripts are refused (an injected ``<script>`` does not run); inline style
attributes are allowed because the tiles draw their meters with them. Only this origin may
embed an answer (CORP): the session cookie is SameSite, and a page on another port of the
same host, or another name of the same site, is same-site, so its ``<img>`` of an image URL
went out with the operator's cookie and loaded (an oracle of which images and drones
exist, and their sizes)."""

_SECRET_PARAM = re.compile(r"((?:^|[?&;])(?:token|login|access_token|key)=)[^&;#\s\"]*",
                           re.I)


def redact(text: str) -> str:
    """``text`` with the values of token-like query parameters replaced by ``***``."""
    return _SECRET_PARAM.sub(r"\1***", text)


async def add_security_headers(request: web.Request, response: web.StreamResponse) -> None:
    for name, value in SECURITY_HEADERS.items():
        response.headers.setdefault(name, value)
    response.headers.update(cache_policy(request.path, response))


def cache_policy(path: str, response: web.StreamResponse) -> dict[str, str]:
    """``Cache-Control`` for a response: nothing a browser or a proxy could keep holds fleet
    data or a credential.

    The fleet's data (``/api/``, the WebSocket) and anything that sets a cookie are
    ``no-store`` whatever the handler said: a shared computer's browser cache, or a proxy
    between the operator and the station, would otherwise keep positions, images and
    reports on disk after the session. Every other answer (the HTML shells, errors) is
    ``no-store`` unless its handler chose (the shells say ``no-cache``: no data in them);
    ``/static/`` (the dashboard's own code, versioned URLs) keeps aiohttp's validators."""
    if path.startswith(("/api/", "/ws")) or response.cookies:
        return {"Cache-Control": "no-store"}
    if path.startswith("/static/") or "Cache-Control" in response.headers:
        return {}
    return {"Cache-Control": "no-store"}


def same_origin(request: web.Request) -> bool:
    """True when the request's ``Origin`` is this server (as the browser addressed it)."""
    origin = request.headers.get("Origin")
    return origin is not None and origin == f"{request.scheme}://{request.host}"


class RedactingAccessLogger(AbstractAccessLogger):
    """aiohttp's default access-log line, with secrets removed from the request line and
    the Referer."""

    def log(self, request: web.BaseRequest, response: web.StreamResponse, time: float) -> None:
        if not self.logger.isEnabledFor(logging.INFO):
            return
        line = redact(f"{request.method} {request.path_qs} HTTP/{request.version.major}."
                      f"{request.version.minor}")
        referer = redact(request.headers.get("Referer", "-"))
        agent = request.headers.get("User-Agent", "-")
        self.logger.info('%s "%s" %d %d "%s" "%s" %.3fs', request.remote, line,
                         response.status, response.body_length, referer, agent, time)


class UnparsableRequestFilter(logging.Filter):
    """aiohttp logs a request it cannot parse (an unknown method, an 8 kB header, a NUL in
    the URL: a port scanner or an attacker) as an ERROR with a traceback that quotes the
    raw bytes, a cookie or token among them. Such a record becomes one WARNING line naming
    the client and the error class; the 400 reply is :class:`FixedErrorPages`'s fixed one."""

    def filter(self, record: logging.LogRecord) -> bool:
        exc = record.exc_info[1] if record.exc_info else None
        if isinstance(exc, HttpProcessingError):
            client = record.args[0] if isinstance(record.args, tuple) and record.args else "?"
            record.msg, record.args = "HTTP request refused (%s %s) from %s", (
                exc.code, type(exc).__name__, client)
            record.exc_info, record.exc_text = None, None
            record.levelno, record.levelname = logging.WARNING, "WARNING"
        return True


_UNPARSABLE_FILTER = UnparsableRequestFilter()

MALFORMED_REQUEST_BODY = "400 Bad Request: malformed HTTP request\n"


class FixedErrorPages(RequestHandler):
    """aiohttp's connection handler, whose error replies quote nothing of the request.

    For a request its parser refuses, aiohttp's 400 page echoes the offending request line,
    header line or chunk-size line (a cookie, or markup a browser might render: reflected
    input). ``handle_error`` is where aiohttp builds that page for parser errors (no
    middleware sees them); here it still logs as aiohttp does (one line, through
    :class:`UnparsableRequestFilter`) but answers with a fixed body and the security headers.
    """

    __slots__ = ()

    def handle_error(self, request: web.BaseRequest, status: int = 500,
                     exc: BaseException | None = None,
                     message: str | None = None) -> web.StreamResponse:
        response = super().handle_error(request, status, exc, message)  # logs, closes
        if isinstance(exc, HttpProcessingError) or status == 400:
            response = web.Response(status=400, text=MALFORMED_REQUEST_BODY)
            response.force_close()
        response.headers.update(SECURITY_HEADERS)
        return response


class _Refused(asyncio.Protocol):
    """Closes a connection beyond the cap at once (its descriptor is freed immediately)."""

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        transport.abort()  # type: ignore[attr-defined]


def _peer_host(transport: asyncio.BaseTransport | None) -> str | None:
    peer = transport.get_extra_info("peername") if transport is not None else None
    return str(peer[0]) if isinstance(peer, tuple) and peer else None


class _Admission(asyncio.Protocol):
    """A connection's first protocol: once the peer's address is known, it is either
    closed (that address holds its share already) or handed to aiohttp's handler."""

    def __init__(self, site: LimitedSite) -> None:
        self._site = site

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self._site.admit(transport)


class LimitedSite(web.BaseSite):
    """A TCP site that serves at most ``max_connections`` connections at a time, at most
    ``max_per_client`` of them from one address: a host on the network cannot hold them
    all (idle, reopened every idle timeout) and lock the operator out without a token."""

    __slots__ = ("_host", "_max_connections", "_max_per_client", "_port", "refused",
                 "refused_client")

    def __init__(self, runner: web.BaseRunner, host: str, port: int, *,
                 max_connections: int, max_per_client: int | None = None) -> None:
        super().__init__(runner)
        self._host = host
        self._port = port
        self._max_connections = max_connections
        self._max_per_client = max_connections if max_per_client is None else max_per_client
        self.refused = 0
        self.refused_client = 0

    @property
    def name(self) -> str:
        return f"http://{self._host}:{self._port}"

    def _protocol(self) -> asyncio.Protocol:
        server = self._runner.server
        assert server is not None
        if len(server.connections) >= self._max_connections:
            self.refused += 1
            if worth_logging(self.refused):
                log.warning("HTTP connection refused: %d open (cap %d); %d refused so far",
                            len(server.connections), self._max_connections, self.refused)
            return _Refused()
        return _Admission(self)

    def admit(self, transport: asyncio.BaseTransport) -> None:
        """Serve a new connection, or close it when its address holds its share."""
        server = self._runner.server
        assert server is not None
        client = _peer_host(transport)
        held = sum(1 for h in server.connections if _peer_host(h.transport) == client)
        if client is not None and held >= self._max_per_client:
            self.refused_client += 1
            if worth_logging(self.refused_client):
                log.warning("HTTP connection from %s refused: it holds %d "
                            "(http_max_per_client); %d refused so far", client, held,
                            self.refused_client)
            transport.abort()  # type: ignore[attr-defined]
            return
        handler: RequestHandler = server()
        handler.__class__ = FixedErrorPages  # same slots: only handle_error differs
        transport.set_protocol(handler)
        handler.connection_made(transport)

    async def start(self) -> None:
        await super().start()
        loop = asyncio.get_running_loop()
        self._server = await loop.create_server(self._protocol, self._host, self._port,
                                                reuse_address=True)


def raise_open_file_limit() -> tuple[int, int] | None:
    """Raise the soft RLIMIT_NOFILE to the hard limit; returns (soft, hard) now, or None."""
    try:
        import resource
    except ImportError:  # pragma: no cover - not POSIX
        return None
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard != resource.RLIM_INFINITY and soft < hard:
        try:
            resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))
            soft = hard
        except (ValueError, OSError) as exc:  # pragma: no cover - depends on the host
            log.warning("open-file limit stays %d: %s", soft, exc)
    return soft, hard


_last_resource_warning = 0.0


def _loop_exception(loop: asyncio.AbstractEventLoop, context: dict[str, Any]) -> None:
    """Out of file descriptors while accepting (asyncio pauses accepting for a second and
    retries): one warning line at most every 10 s, not a traceback per attempt. Anything
    else goes to asyncio's default handler."""
    global _last_resource_warning
    exc = context.get("exception")
    if context.get("message", "").startswith("socket.accept() out of system resource") \
            and isinstance(exc, OSError):
        now = time.monotonic()
        if now - _last_resource_warning >= 10.0:
            _last_resource_warning = now
            log.warning("HTTP: cannot accept a connection (%s); retrying", exc.strerror or exc)
        return
    loop.default_exception_handler(context)


def serve(app: web.Application, *, host: str, port: int, max_connections: int,
          idle_timeout_s: float, max_per_client: int | None = None,
          stop_signals: EarlyStop | None = None,
          on_serving: Callable[[int], None] | None = None) -> None:
    """``web.run_app`` with the connection cap, idle timeout and redacting access log.

    Returns when SIGINT/SIGTERM stops the server (after the app's cleanup ran), including
    one that ``stop_signals`` caught before the server started. OSError (address in
    use...) propagates to the caller. ``on_serving(port)`` runs once the site listens, with
    the port it got (``port=0`` picks one), so a URL shown to a person is one that answers.
    """
    early = EarlyStop() if stop_signals is None else stop_signals
    logging.getLogger("aiohttp.server").addFilter(_UNPARSABLE_FILTER)  # idempotent

    async def main() -> None:
        loop = asyncio.get_running_loop()
        loop.set_exception_handler(_loop_exception)
        # Our own SIGINT/SIGTERM handlers before anything awaits: a Ctrl-C during the app's
        # startup then stops the server once startup is done, instead of cancelling the
        # startup (a cancellation lost inside it left the station serving after Ctrl-C).
        stop = asyncio.Event()
        early.attach(loop, stop.set)
        runner = web.AppRunner(app, handle_signals=False, access_log_class=RedactingAccessLogger,
                               keepalive_timeout=idle_timeout_s)
        try:
            await runner.setup()
            if not stop.is_set():
                site = LimitedSite(runner, host, port, max_connections=max_connections,
                                   max_per_client=max_per_client)
                await site.start()
                if on_serving is not None:
                    on_serving(int(runner.addresses[0][1]))
                await stop.wait()
        finally:
            for sig in STOP_SIGNALS:  # a second Ctrl-C forces the exit
                loop.remove_signal_handler(sig)
            await runner.cleanup()

    t0 = time.monotonic()
    try:
        asyncio.run(main())
    except (web.GracefulExit, KeyboardInterrupt):
        log.debug("HTTP server stopped after %.1f s", time.monotonic() - t0)


def json_reply(data: Any, status: int = 200) -> web.Response:
    """JSON with anything unusual (paths, times) as text: the API's one reply shape."""
    return web.json_response(data, status=status, dumps=lambda v: json.dumps(v, default=str))
