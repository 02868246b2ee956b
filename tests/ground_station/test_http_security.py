"""HTTP hardening (issue 13 item 6), in process: where the token may come from, the one-time
login link, same-origin rules for the cookie and the WebSocket, security headers."""

from __future__ import annotations

import time
from typing import Any

import aiohttp
import pytest
from aiohttp.test_utils import TestClient

from ground_station.http_guard import SECURITY_HEADERS, redact
from ground_station.token import SESSION_COOKIE, login_code, page_key, session_value

TOKEN = "test-token-0123456789"  # as in conftest.gs_client


def auth() -> dict[str, str]:
    return {"Authorization": f"Bearer {TOKEN}"}


def origin(client: TestClient[Any, Any]) -> str:
    return f"http://{client.host}:{client.port}"


async def test_a_token_in_the_url_is_refused(gs_client: TestClient[Any, Any]) -> None:
    resp = await gs_client.post(f"/api/mission/start?token={TOKEN}", json={"delay_s": 1})
    assert resp.status == 401
    assert (await gs_client.get(f"/api/stats?token={TOKEN}")).status == 401
    assert (await gs_client.post("/api/mission/start", json={"delay_s": 1},
                                 headers=auth())).status == 200


@pytest.mark.parametrize("path", ["/", "/static/app.js", "/api/stats", "/nowhere"])
async def test_security_headers_on_every_response(gs_client: TestClient[Any, Any],
                                                  path: str) -> None:
    resp = await gs_client.get(path)
    for name, value in SECURITY_HEADERS.items():
        assert resp.headers.get(name) == value, (path, name)
    assert "frame-ancestors 'none'" in resp.headers["Content-Security-Policy"]
    assert "script-src 'self'" in resp.headers["Content-Security-Policy"]


async def test_one_time_login_link(gs_client: TestClient[Any, Any]) -> None:
    code = login_code(TOKEN, now=time.time())
    resp = await gs_client.get(f"/?login={code}&mission=m1", allow_redirects=False)
    key = page_key(TOKEN)  # for the page only: in the fragment, which no server sees
    assert resp.status == 303 and resp.headers["Location"] == f"/?mission=m1#key={key}"
    cookie = resp.cookies[SESSION_COOKIE]
    assert cookie.value == session_value(TOKEN) != TOKEN
    assert cookie["httponly"] and cookie["samesite"] == "Strict"
    jar = {SESSION_COOKIE: cookie.value}
    assert (await gs_client.get("/api/stats", cookies=jar,
                                headers={"X-GS-Key": key})).status == 200
    assert (await gs_client.get(f"/api/stats?key={key}", cookies=jar)).status == 200
    # the cookie alone (what any other port of this host gets) opens nothing
    assert (await gs_client.get("/api/stats", cookies=jar)).status == 401
    assert (await gs_client.get("/api/stats", cookies=jar,
                                headers={"X-GS-Key": key[:-1] + "x"})).status == 401
    # once only; forged, expired and plain tokens in the URL give no session
    for url in (f"/?login={code}",
                f"/?login={code[:-1]}{'0' if code[-1] != '0' else '1'}",
                f"/?login={login_code(TOKEN, now=time.time() - 3600)}",
                f"/?login={login_code('another token', now=time.time())}",
                f"/?token={TOKEN}"):
        again = await gs_client.get(url, allow_redirects=False)
        assert again.status == 303 and SESSION_COOKIE not in again.cookies, url
        assert "login=" not in again.headers["Location"]
        assert "token=" not in again.headers["Location"]
        assert "key=" not in again.headers["Location"]


async def test_the_cookie_commands_only_from_this_origin(
    gs_client: TestClient[Any, Any],
) -> None:
    jar = {SESSION_COOKIE: session_value(TOKEN)}
    key = {"X-GS-Key": page_key(TOKEN)}
    body = {"delay_s": 5}
    assert (await gs_client.post("/api/mission/start", json=body, cookies=jar,
                                 headers=key)).status == 401
    foreign = {"Origin": "http://evil.example", **key}
    assert (await gs_client.post("/api/mission/start", json=body, cookies=jar,
                                 headers=foreign)).status == 401
    own = {"Origin": origin(gs_client)}  # the cookie and this origin, but not the page key
    assert (await gs_client.post("/api/mission/start", json=body, cookies=jar,
                                 headers=own)).status == 401
    assert (await gs_client.post("/api/mission/start", json=body, cookies=jar,
                                 headers={**own, **key})).status == 200
    wrong = {SESSION_COOKIE: session_value("not the token")}
    assert (await gs_client.get("/api/stats", cookies=wrong)).status == 401


async def test_token_box_login_sets_the_cookie(gs_client: TestClient[Any, Any]) -> None:
    assert (await gs_client.post("/api/login",
                                 headers={"Authorization": "Bearer wrong"})).status == 401
    resp = await gs_client.post("/api/login", headers=auth())
    assert resp.status == 200 and await resp.json() == {"key": page_key(TOKEN)}
    assert resp.cookies[SESSION_COOKIE].value == session_value(TOKEN)
    # the cookie alone, even from this origin, cannot fetch the page key
    cookie = {"Cookie": f"{SESSION_COOKIE}={session_value(TOKEN)}", "Origin": origin(gs_client)}
    assert (await gs_client.post("/api/login", headers=cookie)).status == 401


async def test_websocket_refuses_other_origins(gs_client: TestClient[Any, Any]) -> None:
    cookie = f"{SESSION_COOKIE}={session_value(TOKEN)}"
    keyed = f"/ws?key={page_key(TOKEN)}"
    with pytest.raises(aiohttp.WSServerHandshakeError) as info:
        await gs_client.ws_connect(
            keyed, headers={"Origin": "http://evil.example", "Cookie": cookie})
    assert info.value.status == 403
    with pytest.raises(aiohttp.WSServerHandshakeError) as info:  # no page key
        await gs_client.ws_connect("/ws", headers={"Origin": origin(gs_client),
                                                   "Cookie": cookie})
    assert info.value.status == 401
    ws = await gs_client.ws_connect(keyed, headers={"Origin": origin(gs_client),
                                                    "Cookie": cookie})
    first = await ws.receive_json(timeout=5)
    assert first["kind"] == "snapshot"
    await ws.close()


def test_redact_hides_token_like_parameters() -> None:
    line = "GET /?login=abc.def&x=1&token=s3cret;access_token=zz HTTP/1.1"
    assert redact(line) == "GET /?login=***&x=1&token=***;access_token=*** HTTP/1.1"
    assert redact("http://h/p?TOKEN=abc#frag") == "http://h/p?TOKEN=***#frag"
