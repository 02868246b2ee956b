"""No cache keeps the fleet's data, no log or answer shows a credential (2026-11-25).

The shipped ``uav-ground-station run`` (a real subprocess, INFO logging to a file, as a
service's journal would hold it) holds one real image; every GET route of the router is read
with the token. Every data answer, the login's cookie-setting answers and the errors say
``Cache-Control: no-store`` (before: none at all, and ``no-cache`` on the report's PNG: a
shared computer's browser cache or a proxy kept positions, images and reports). Then the
token, the session cookie and a login code are sent every way a client might (header, URL,
Referer, a request too long to parse): none of them is in the log, and no API answer holds
the token or the session value.
"""

from __future__ import annotations

import asyncio
import socket
import subprocess
import sys
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

import aiohttp

from ground_station.app import create_app
from ground_station.config import GroundConfig
from ground_station.fake_drone import FakeDrone, synthetic_jpeg
from ground_station.token import SESSION_COOKIE, page_key, session_value
from tests.integration.test_ground_station_cli import free_port, wait_http
from tests.keys import TEST_COMMAND_KEY, TEST_FLEET_KEY, write_test_keys
from tests.processes import interrupt

STATION = Path(sys.executable).parent / "uav-ground-station"

SHELLS = {"/", "/report"}
"""The two HTML pages: no data in them (the data comes from /api/), so ``no-cache``."""


def _get_routes() -> set[str]:
    app = create_app(GroundConfig(fleet_key=b"x" * 32, command_key=TEST_COMMAND_KEY),
                     token="unused-token-0123456789")
    return {resource.canonical for resource in app.router.resources()
            for route in resource if route.method == "GET"}


def _concrete(canonical: str, image_id: int) -> str:
    return (canonical.replace("{image_id}", str(image_id)).replace("{drone}", "uav1")
            .replace("/static", "/static/app.js"))


async def _raw(port: int, request: bytes) -> bytes:
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(request)
    await writer.drain()
    try:
        async with asyncio.timeout(5):
            return await reader.read(65536)
    finally:
        writer.close()


async def test_no_cache_keeps_data_and_no_log_shows_a_secret(tmp_path: Path) -> None:
    udp_port, http_port = free_port(socket.SOCK_DGRAM), free_port(socket.SOCK_STREAM)
    data = tmp_path / "data"
    write_test_keys(data / "keys")
    log = tmp_path / "station.log"
    with open(log, "w") as stderr:
        station = subprocess.Popen(
            [str(STATION), "run", "--data-dir", str(data), "--mission", "m",
             "--udp-port", str(udp_port), "--http-port", str(http_port)],
            stdout=subprocess.PIPE, stderr=stderr, text=True)
    base = f"http://127.0.0.1:{http_port}"
    drone = FakeDrone("uav1", fleet_id=1, key=TEST_FLEET_KEY, ground=("127.0.0.1", udp_port))
    try:
        assert station.stdout is not None
        printed = [station.stdout.readline(), station.stdout.readline()]
        token = (data / "token").read_text().strip()
        assert token in printed[0]  # on the terminal, once, as documented
        code = parse_qs(urlsplit(printed[1].split()[1]).query)["login"][0]
        session, key = session_value(token), page_key(token)
        await wait_http(base + "/api/stats")
        await drone.open()
        drone.send_image(synthetic_jpeg(1, red=0.3, label="uav1"),
                         data={"red": 0.3, "lat_deg": 47.1, "lon_deg": 8.5})
        auth = {"Authorization": f"Bearer {token}"}
        async with aiohttp.ClientSession() as http:
            async with asyncio.timeout(15):
                while True:
                    async with http.get(base + "/api/images?mission=m", headers=auth) as resp:
                        images = (await resp.json())["images"]
                    if images:
                        break
                    await asyncio.sleep(0.2)
            routes = _get_routes()
            assert len(routes) >= 14, routes
            answers: list[str] = []
            for canonical in sorted(routes - {"/ws"}):
                url = base + _concrete(canonical, images[0]["id"]) + "?mission=m"
                async with http.get(url, headers=auth) as resp:
                    assert resp.status == 200, (canonical, resp.status)
                    cache = resp.headers.get("Cache-Control")
                    body = await resp.read()
                if canonical in SHELLS:
                    assert cache == "no-cache", canonical
                elif canonical == "/static":
                    assert cache is None  # the dashboard's code, public, versioned URLs
                else:
                    assert cache == "no-store", (canonical, cache)
                    answers.append(body.decode("latin-1"))
                if canonical.startswith("/api/"):  # the token is refused: still no-store
                    async with http.get(url) as resp:
                        assert (resp.status, resp.headers.get("Cache-Control")) == (
                            401, "no-store"), canonical
            ws = await http.ws_connect(base + "/ws", headers=auth)
            answers.append(str(await ws.receive_json(timeout=5)))
            await ws.close()
            async with http.post(base + "/api/login", headers=auth) as resp:
                assert resp.status == 200 and SESSION_COOKIE in resp.cookies
                assert resp.headers["Cache-Control"] == "no-store"
            async with http.get(f"{base}/?login={code}&token={token}", allow_redirects=False,
                                headers={"Referer": f"{base}/?token={token}&login={code}"}
                                ) as resp:
                assert resp.status == 303 and SESSION_COOKIE in resp.cookies
                assert resp.headers["Cache-Control"] == "no-store"
            async with http.get(f"{base}/api/stats?token={token}&key={key}",
                                headers={"Cookie": f"{SESSION_COOKIE}={session}"}) as resp:
                assert resp.status == 200 and resp.headers["Cache-Control"] == "no-store"
        cookie_line = f"Cookie: {SESSION_COOKIE}={session}; x={'a' * 9000}\r\n".encode()
        reply = await _raw(http_port, b"GET /api/stats HTTP/1.1\r\nHost: 127.0.0.1\r\n"
                           + cookie_line + b"\r\n")
        assert reply.split(b"\r\n")[0].endswith(b" 400 Bad Request")
        assert session.encode() not in reply
        assert station.poll() is None
    finally:
        drone.close()
        interrupt(station, timeout_s=20)
    text = log.read_text()
    assert station.returncode == 0 and "Traceback" not in text
    assert "GET /?login=***&token=***" in text  # the requests were logged, redacted
    assert "GET /api/stats?token=***&key=***" in text
    for secret in (token, session, key, code, code.split(".")[1]):
        assert secret not in text
        assert not any(secret in answer for answer in answers)
