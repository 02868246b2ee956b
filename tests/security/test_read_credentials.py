"""Least privilege for reads (2026-11-25): the shipped ``uav-ground-station run`` without
``public_read`` (the default), every data route the router has (GET ``/api/...`` and the
WebSocket) with every credential that must not open it: none, a login code, the fleet key,
the session value or the page key sent as a token, the token in the URL, the session cookie
alone or with this page's ``Origin`` (what a server on another port of this host gets), the
cookie with another token's page key, the page key alone. Every one is 401 and sets no
cookie; the token header and the dashboard's session (cookie and page key) are 200.
"""

from __future__ import annotations

import socket
import subprocess
import sys
import time
from pathlib import Path

import aiohttp

from ground_station.app import create_app
from ground_station.config import GroundConfig
from ground_station.token import SESSION_COOKIE, login_code, page_key, session_value
from tests.integration.test_ground_station_cli import free_port, wait_http
from tests.keys import TEST_COMMAND_KEY, write_test_keys
from tests.processes import interrupt

STATION = Path(sys.executable).parent / "uav-ground-station"


def _data_routes() -> list[str]:
    app = create_app(GroundConfig(fleet_key=b"x" * 32, command_key=TEST_COMMAND_KEY),
                     token="unused-token-0123456789")
    paths = sorted({resource.canonical for resource in app.router.resources()
                    for route in resource if route.method == "GET"
                    and (resource.canonical.startswith("/api/") or resource.canonical == "/ws")})
    assert len(paths) >= 12 and "/ws" in paths and "/api/report.png" in paths, paths
    return [p.replace("{image_id}", "1").replace("{drone}", "uav1") for p in paths]


async def test_no_credential_but_the_token_or_the_session_reads(tmp_path: Path) -> None:
    data = tmp_path / "data"
    keys = write_test_keys(data / "keys")
    http_port = free_port(socket.SOCK_STREAM)
    station = subprocess.Popen(
        [str(STATION), "run", "--data-dir", str(data), "--udp-port", "0",
         "--http-port", str(http_port)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
        text=True)
    base = f"http://127.0.0.1:{http_port}"
    try:
        await wait_http(base + "/api/stats")
        token = (data / "token").read_text().strip()
        here = {"Origin": base}
        cookie = {"Cookie": f"{SESSION_COOKIE}={session_value(token)}"}
        refused: dict[str, dict[str, str]] = {
            "none": {}, "none, this origin": here,
            "login code as token": {
                "Authorization": f"Bearer {login_code(token, now=time.time())}"},
            "fleet key as token": {
                "Authorization": f"Bearer {(keys / 'fleet.key').read_text().strip()}"},
            "session value as token": {"X-GS-Token": session_value(token)},
            "page key as token": {"Authorization": f"Bearer {page_key(token)}"},
            "token in the URL": {},
            "cookie alone": cookie, "cookie, this origin": {**cookie, **here},
            "cookie, another token's page key": {**cookie, "X-GS-Key": page_key(token + "x")},
            "page key alone": {"X-GS-Key": page_key(token), **here},
        }
        granted = {"token": {"Authorization": f"Bearer {token}"},
                   "session": {**cookie, "X-GS-Key": page_key(token)}}
        async with aiohttp.ClientSession() as http:
            tried = 0
            for path in _data_routes():
                for what, headers in refused.items():
                    url = base + path + (f"?token={token}" if what == "token in the URL" else "")
                    async with http.get(url, headers=headers) as resp:
                        assert resp.status == 401, (path, what, resp.status)
                        assert "Set-Cookie" not in resp.headers, (path, what)
                    tried += 1
                for what, headers in granted.items():
                    if path == "/ws":
                        ws = await http.ws_connect(base + path, headers=headers)
                        assert (await ws.receive_json(timeout=5))["kind"] == "snapshot"
                        await ws.close()
                        continue
                    async with http.get(base + path, headers=headers) as resp:  # 404: no such
                        assert resp.status in (200, 404), (path, what, resp.status)  # image
            assert tried == len(_data_routes()) * len(refused)
        assert station.poll() is None
    finally:
        interrupt(station, timeout_s=20)
        _, err = station.communicate()
    assert station.returncode == 0 and "Traceback" not in err
