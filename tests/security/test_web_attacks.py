"""Attacks on the ground station's web side (docs/security.md): hostile query strings on the
report routes, path tricks on file routes, oversized bodies, cross-site and unauthenticated
state changes, leaky errors. Every state-changing route is found from the router, so a route
added later without protection fails here."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import pytest
from aiohttp.test_utils import TestClient

from ground_station.config import GroundConfig
from ground_station.token import SESSION_COOKIE, page_key, session_value

TOKEN = "test-token-0123456789"  # as in tests/ground_station/conftest.py
AUTH = {"Authorization": f"Bearer {TOKEN}"}


def _files(root: Path) -> set[Path]:
    return {p for p in root.rglob("*") if p.is_file()} if root.exists() else set()


@pytest.mark.parametrize("mission", ["../../escape", "nosuch", "a\x00b", "/etc", ".hidden",
                                     "x" * 5000])
async def test_a_report_read_writes_nothing_for_unknown_missions(
        gs_client: TestClient[Any, Any], gs_config: GroundConfig, tmp_path: Path,
        mission: str) -> None:
    """GET /api/report.png once created DATA_DIR/missions/<any query>/utility.png: a read
    that fills the disk (one folder per request) and 500s on a NUL byte."""
    before = _files(gs_config.data_dir / "missions")
    resp = await gs_client.get("/api/report.png", params={"mission": mission}, headers=AUTH)
    assert resp.status == 200 and resp.content_type == "image/png"
    assert (await resp.read())[:4] == b"\x89PNG"
    assert _files(gs_config.data_dir / "missions") - before == set()
    assert not (tmp_path / "escape").exists()


@pytest.mark.parametrize("path", [
    "/api/images/..%2f..%2fetc%2fpasswd.jpg", "/api/images/%2fetc%2fpasswd.jpg",
    "/api/images/-1.jpg", "/api/images/1e3.jpg", "/api/images/99999999999999999999.jpg",
    "/static/..%2f..%2fconfig.py", "/static/%2e%2e/%2e%2e/config.py", "/static//etc/passwd",
    "/api/drones/..%2f..%2fetc/latest.jpg",
])
async def test_file_routes_refuse_path_tricks(gs_client: TestClient[Any, Any],
                                              path: str) -> None:
    resp = await gs_client.get(path, headers=AUTH)
    assert resp.status in (403, 404), (path, resp.status)
    body = await resp.read()
    assert b"root:" not in body and b"GroundConfig" not in body


async def test_static_files_do_not_follow_symlinks_out(gs_client: TestClient[Any, Any]) -> None:
    from ground_station.auth import STATIC_DIR

    link = STATIC_DIR / "sec-test-link.txt"
    if not os.access(STATIC_DIR, os.W_OK):
        pytest.skip(f"{STATIC_DIR} is not writable: cannot plant the symlink")
    link.symlink_to("/etc/hostname")
    try:
        assert (await gs_client.get("/static/sec-test-link.txt")).status in (403, 404)
    finally:
        link.unlink()


async def test_an_oversized_body_is_refused_before_it_is_read(
        gs_client: TestClient[Any, Any]) -> None:
    resp = await gs_client.post("/api/mission/params", data=b"{" + b" " * (2 << 20) + b"}",
                                headers=AUTH | {"Content-Type": "application/json"})
    assert resp.status == 413


def _state_changing(client: TestClient[Any, Any]) -> list[str]:
    routes = []
    for resource in client.app.router.resources():
        for route in resource:
            if route.method not in ("GET", "HEAD", "OPTIONS", "*"):
                routes.append(resource.canonical)
    return sorted(set(routes))


async def test_every_state_change_needs_the_token_and_this_origin(
        gs_client: TestClient[Any, Any]) -> None:
    routes = _state_changing(gs_client)
    assert "/api/mission/start" in routes and "/api/mission/end" in routes
    here = f"http://{gs_client.host}:{gs_client.port}"
    cookie = {SESSION_COOKIE: session_value(TOKEN)}
    for path in routes:
        assert (await gs_client.post(path, json={})).status == 401, path
        assert (await gs_client.post(path, json={}, headers={
            "Authorization": f"Bearer {TOKEN[:-1]}x"})).status == 401, path
        gs_client.session.cookie_jar.update_cookies(cookie)
        try:
            key = {"X-GS-Key": page_key(TOKEN)}
            for hostile in ({"Origin": "http://evil.example", **key}, {"Origin": "null", **key},
                            key, {"Origin": here}):  # the last: the cookie, no page key
                resp = await gs_client.post(path, json={}, headers=hostile)
                assert resp.status == 401, (path, hostile, resp.status)
            resp = await gs_client.post(path, json={}, headers={"Origin": here, **key})
            assert resp.status != 401, path
        finally:
            gs_client.session.cookie_jar.clear()


async def test_no_get_route_changes_the_mission(gs_client: TestClient[Any, Any]) -> None:
    for path in ("/api/mission/start", "/api/mission/end", "/api/mission/params",
                 "/api/login"):
        assert (await gs_client.get(path, headers=AUTH)).status in (404, 405), path
    state = await (await gs_client.get("/api/mission", headers=AUTH)).json()
    assert not state.get("commands")


async def test_login_cookie_is_httponly_and_strict(gs_client: TestClient[Any, Any]) -> None:
    resp = await gs_client.post("/api/login", headers=AUTH)
    assert resp.status == 200
    morsel = resp.cookies[SESSION_COOKIE]
    assert morsel["httponly"] and morsel["samesite"] == "Strict"
    assert morsel.value != TOKEN


@pytest.mark.parametrize("body", [b"{", b"[]", b'{"delay_s": "NaN"}', b'{"delay_s": 1e999}',
                                  b"\xff\xfe", b'{"name": "' + b"\\ud800" + b'"}',
                                  b'{"a": ' + b"[" * 200_000 + b"]" * 200_000 + b"}",
                                  b'{"delay_s": [1]}', b'{"t_exec": true}',
                                  b'{"params": {"alpha": [[{}]]}}', b'{"when": "at 99:99"}',
                                  b'{"params": "' + b"a=" * 1000 + b'"}', b'{"delay_s": -1e308}',
                                  # 2026-11-25: a 5000-digit integer (past Python's int
                                  # parsing limit), 1e999999, NaN, 50 000 nested objects,
                                  # 60 000 parameters, a NUL and a bidi override in a value
                                  b'{"t_exec": ' + b"1" * 5000 + b"}",
                                  b'{"t_exec": 1e999999}', b'{"t_exec": NaN}',
                                  b'{"a":' * 50_000 + b"1" + b"}" * 50_000,
                                  b'{"params": {' + b",".join(
                                      b'"a%d": 1' % i for i in range(60_000)) + b"}}",
                                  b'{"params": {"x": "\\u0000\\u202e"}}'])
async def test_bad_bodies_get_a_short_error_without_a_traceback(
        gs_client: TestClient[Any, Any], body: bytes) -> None:
    for path in ("/api/mission/start", "/api/mission/params"):
        resp = await gs_client.post(path, data=body,
                                    headers=AUTH | {"Content-Type": "application/json"})
        assert resp.status in (200, 400, 409, 422), (path, body, resp.status)
        text = await resp.text()
        assert "Traceback" not in text and "File \"" not in text, text


def test_secure_defaults() -> None:
    """Loopback only, no key, no public reads unless the operator says so."""
    config = GroundConfig()
    assert (config.http_host, config.udp_host) == ("127.0.0.1", "127.0.0.1")
    assert config.fleet_key is None and config.command_key is None
    assert not config.public_read
