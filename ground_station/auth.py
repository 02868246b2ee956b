"""Who may use the ground station's HTTP API: the control-token middleware and the dashboard
login (a one-time code or the token box exchanged for an HttpOnly session cookie).
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from pathlib import Path

from aiohttp import web

from ground_station.http_guard import json_reply, same_origin
from ground_station.keys import CLOCK, CONFIG, TOKEN
from ground_station.token import (
    PAGE_KEY_HEADER,
    SESSION_COOKIE,
    LoginCodes,
    page_key,
    session_value,
    token_matches,
)

__all__ = ["LOGIN_CODES", "STATIC_DIR", "api_login", "index", "token_middleware"]

STATIC_DIR = Path(__file__).parent / "static"
LOGIN_CODES: web.AppKey[LoginCodes] = web.AppKey("login_codes")
Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]


def _header_token(request: web.Request) -> str | None:
    """The token from a header; never from the URL (URLs end up in logs and histories)."""
    auth = request.headers.get("Authorization", "")
    if auth.startswith("Bearer "):
        return auth[7:].strip()
    return request.headers.get("X-GS-Token")


def _authorized(request: web.Request, *, control: bool) -> bool:
    """A header token, or the dashboard's session: the HttpOnly cookie together with the
    page key (``token.page_key``: the cookie also goes to other ports of this host). With
    the session, control requests must also come from this origin (a SameSite=Strict
    cookie plus an Origin check: no cross-site request forgery)."""
    token = request.app[TOKEN]
    given = _header_token(request)
    if given is not None:
        return token_matches(token, given)
    cookie = request.cookies.get(SESSION_COOKIE)
    if cookie is None or not token_matches(session_value(token), cookie):
        return False
    key = request.headers.get(PAGE_KEY_HEADER, request.query.get("key"))
    if not token_matches(page_key(token), key):
        return False
    return not control or same_origin(request)


def _is_control(request: web.Request) -> bool:
    return request.path.startswith("/api/") and request.method not in ("GET", "HEAD", "OPTIONS")


def _is_data_read(request: web.Request) -> bool:
    return request.path.startswith("/api/") or request.path == "/ws"


@web.middleware
async def token_middleware(request: web.Request, handler: Handler) -> web.StreamResponse:
    """The single place the control token is checked (control routes; reads unless public)."""
    app = request.app
    control = _is_control(request)
    needs = control or (_is_data_read(request) and not app[CONFIG].public_read)
    if needs and not _authorized(request, control=control):
        return json_reply(
            {"error": "unauthorized", "hint": "send 'Authorization: Bearer <token>'"}, status=401
        )
    return await handler(request)


def _set_session(response: web.StreamResponse, request: web.Request) -> None:
    response.set_cookie(SESSION_COOKIE, session_value(request.app[TOKEN]), path="/",
                        httponly=True, samesite="Strict", secure=request.secure)


async def index(request: web.Request) -> web.StreamResponse:
    """The dashboard. ``?login=CODE`` (one-time) is exchanged for the session cookie and
    removed from the address bar by a redirect; a token in the URL is never accepted."""
    if "login" in request.query or "token" in request.query:
        code = request.query.get("login")
        kept = [(k, v) for k, v in request.query.items() if k not in ("login", "token")]
        target = str(request.rel_url.with_query(kept))
        if code is not None and request.app[LOGIN_CODES].redeem(code, now=request.app[CLOCK]()):
            # the page key rides in the fragment: never sent to a server, read by app.js,
            # which stores it and takes it out of the address bar
            response = web.HTTPSeeOther(location=f"{target}#key={page_key(request.app[TOKEN])}")
            _set_session(response, request)
        else:
            response = web.HTTPSeeOther(location=target)
        raise response
    return web.FileResponse(STATIC_DIR / "index.html", headers={"Cache-Control": "no-cache"})


async def api_login(request: web.Request) -> web.Response:
    """The token box: the token comes in a header (checked by the middleware), the browser
    gets the HttpOnly session cookie and the page key; JavaScript never keeps the token."""
    response = json_reply({"key": page_key(request.app[TOKEN])})
    _set_session(response, request)
    return response
