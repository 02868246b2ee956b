"""Least privilege on the shipped ``uav-ground-station run --public-read`` (2026-11-24).

The station has one read-only credential, none at all (``public_read``), and these others: a
one-time login code, the session cookie it buys, the control token, the fleet key (UDP only)
and the command key (never on the wire). Every route the dashboard lists in its router, with
every method a client can send, is tried with each credential that must not change anything;
the mission (``/api/mission``) must stay as it was and the station must not log a traceback.
"""

from __future__ import annotations

import asyncio
import json
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import aiohttp

from companion.protocol.signing import fleet_key_text
from ground_station.app import create_app
from ground_station.config import GroundConfig
from ground_station.token import SESSION_COOKIE, login_code, page_key, session_value
from tests.integration.test_peers_e2e import free_port
from tests.keys import TEST_COMMAND_KEY, write_test_keys

METHODS = ("POST", "PUT", "PATCH", "DELETE")


def _state_changing_paths() -> list[str]:
    app = create_app(GroundConfig(fleet_key=b"x" * 32, command_key=TEST_COMMAND_KEY),
                     token="unused-token-0123456789")
    paths = {resource.canonical for resource in app.router.resources()
             for route in resource if route.method not in ("GET", "HEAD", "OPTIONS")}
    assert {"/api/mission/start", "/api/mission/end", "/api/mission/params", "/api/login",
            "/api/mission/report", "/api/mission/reports/reset"} <= paths
    return sorted(paths)


async def test_nothing_but_the_token_changes_anything(tmp_path: Path) -> None:
    keys = write_test_keys(tmp_path / "keys")
    port = free_port(socket.SOCK_STREAM)
    config = tmp_path / "gs.toml"
    config.write_text(
        f'[ground_station]\ndata_dir = "data"\nudp_port = 0\nhttp_port = {port}\n'
        f'fleet_key_file = "{keys / "fleet.key"}"\ncommand_key_file = "{keys / "command.key"}"\n')
    gs = Path(sys.executable).parent / "uav-ground-station"
    station = subprocess.Popen([str(gs), "run", "--config", str(config), "--public-read"],
                               cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True)
    base = f"http://127.0.0.1:{port}"
    try:
        assert station.stdout is not None
        for line in station.stdout:
            if line.startswith("dashboard:"):
                break
        token = (tmp_path / "data" / "token").read_text().strip()
        code = login_code(token, now=time.time())
        fleet_key = fleet_key_text((keys / "fleet.key").read_bytes(), "fleet.key").decode()
        async with aiohttp.ClientSession() as http:
            async def mission() -> object:
                async with http.get(base + "/api/mission") as resp:  # a public read
                    assert resp.status == 200
                    return await resp.json()

            before = await mission()
            here = {"Origin": base}
            credentials: dict[str, dict[str, str]] = {
                "none": {}, "none, this origin": here,
                "login code as token": {"Authorization": f"Bearer {code}"},
                "fleet key as token": {"Authorization": f"Bearer {fleet_key}"},
                "session value as token": {"X-GS-Token": session_value(token)},
                "token in the URL": {},
                "cookie, foreign origin": {
                    "Cookie": f"{SESSION_COOKIE}={session_value(token)}",
                    "Origin": "http://evil.example"},
                "cookie, no origin": {"Cookie": f"{SESSION_COOKIE}={session_value(token)}"},
                "cookie of another token": {
                    "Cookie": f"{SESSION_COOKIE}={session_value(token + 'x')}", **here},
                # 2026-11-25: the cookie also reaches other ports of this host, so with
                # this page's Origin it still needs the page key, which alone is nothing
                "cookie, this origin, no page key": {
                    "Cookie": f"{SESSION_COOKIE}={session_value(token)}", **here},
                "cookie, this origin, another token's page key": {
                    "Cookie": f"{SESSION_COOKIE}={session_value(token)}",
                    "X-GS-Key": page_key(token + "x"), **here},
                "page key, this origin": {"X-GS-Key": page_key(token), **here},
                "page key as token": {"Authorization": f"Bearer {page_key(token)}"},
            }
            tried = 0
            for path in _state_changing_paths():
                for method in METHODS:
                    for what, headers in credentials.items():
                        url = base + path + (f"?token={token}" if what == "token in the URL"
                                             else "")
                        async with http.request(method, url, headers=headers,
                                                json={"delay_s": 1, "params": {"alpha": 2}}
                                                ) as resp:
                            assert resp.status in (401, 403, 405), (path, method, what,
                                                                    resp.status)
                            assert "Set-Cookie" not in resp.headers, (path, method, what)
                        tried += 1
            assert tried == len(_state_changing_paths()) * len(METHODS) * len(credentials)
            assert await mission() == before
            # the token itself still works (the sweep refused everything else)
            async with http.post(base + "/api/mission/start", json={"delay_s": 1},
                                 headers={"Authorization": f"Bearer {token}"}) as resp:
                assert resp.status == 200
                assert json.loads(await resp.text())["command"]["name"] == "start"
    finally:
        station.send_signal(signal.SIGINT)
        _, err = await asyncio.to_thread(station.communicate, timeout=30)
    assert station.returncode == 0, err
    assert "Traceback" not in err
