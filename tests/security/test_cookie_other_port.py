"""The session cookie on another port of the station's host (2026-11-25).

Cookies are not isolated by port: after the operator logs in at ``http://127.0.0.1:8080``
the browser sends ``gs_session`` to every server on ``127.0.0.1`` it visits (another user's
program on a shared computer; any local service that logs its requests). Before the page key
(``token.page_key``) that cookie, replayed with a forged ``Origin``, read the fleet and
ended the mission (200). Now the cookie alone opens nothing; the dashboard, logged in by the
login link or by the token box, still reads, draws images and commands. Real headless
Chromium; the replay is a plain HTTP client, as an attacker's would be.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import aiohttp
import pytest
from aiohttp import web

from ground_station.app import create_app
from ground_station.config import GroundConfig
from ground_station.fake_drone import FakeDrone, synthetic_jpeg
from ground_station.keys import LINK
from ground_station.token import SESSION_COOKIE, login_code
from tests.keys import TEST_COMMAND_KEY

CHROMIUM = Path("/usr/bin/chromium")
KEY = b"port-cookie-fleet-key-000000000"
TOKEN = "port-cookie-token-0123456789"

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(not CHROMIUM.exists(),
                       reason="needs Debian chromium: apt-get install chromium"),
]

DASHBOARD_WORKS = """async () => {
  const img = document.querySelector('#gallery img');
  return img !== null && img.complete && img.naturalWidth > 0 &&
    document.querySelector('#conn').className === 'dot on'; }"""


async def _replay(base: str, cookie: str) -> dict[str, int]:
    """What a holder of the cookie alone gets, with this station's Origin forged."""
    headers = {"Cookie": cookie, "Origin": base}
    got = {}
    async with aiohttp.ClientSession() as http:
        for method, path in (("GET", "/api/fleet"), ("GET", "/api/images/1.jpg"),
                             ("POST", "/api/login"), ("POST", "/api/mission/end")):
            async with http.request(method, base + path, headers=headers, json={}) as resp:
                got[f"{method} {path}"] = resp.status
        try:
            ws = await http.ws_connect(base + "/ws", headers=headers)
            got["/ws"] = 101
            await ws.close()
        except aiohttp.WSServerHandshakeError as exc:
            got["/ws"] = exc.status
    return got


async def test_the_cookie_another_port_gets_opens_nothing(
        tmp_path: Path, aiohttp_server: Callable[..., Any]) -> None:
    playwright_api = pytest.importorskip("playwright.async_api")
    config = GroundConfig(fleet_id=6, fleet_key=KEY, command_key=TEST_COMMAND_KEY,
                          data_dir=tmp_path / "gs", mission="port", udp_host="127.0.0.1",
                          udp_port=0, fsync=False)
    station = await aiohttp_server(create_app(config, token=TOKEN))
    drone = FakeDrone("uav1", fleet_id=6, key=KEY, ground=station.app[LINK].local_addr)
    await drone.open()
    drone.send_image(synthetic_jpeg(1, red=0.3, label="uav1"), data={"red": 0.3})
    cookies: list[str | None] = []

    async def other_page(request: web.Request) -> web.Response:
        cookies.append(request.headers.get("Cookie"))
        return web.Response(text="<!doctype html><title>elsewhere</title>",
                            content_type="text/html")

    other = web.Application()
    other.router.add_get("/", other_page)
    elsewhere = await aiohttp_server(other)
    base = f"http://127.0.0.1:{station.port}"
    try:
        async with playwright_api.async_playwright() as pw:
            browser = await pw.chromium.launch(executable_path=str(CHROMIUM), headless=True,
                                               args=["--no-sandbox", "--disable-gpu"])
            for login in ("link", "token box"):
                context = await browser.new_context()
                page = await context.new_page()
                if login == "link":
                    await page.goto(f"{base}/?login={login_code(TOKEN, now=time.time())}")
                    assert page.url == base + "/"  # the key left the address bar
                else:
                    await page.goto(base + "/")
                    await page.fill("#token-input", TOKEN)
                    async with page.expect_navigation():  # the page reloads, logged in
                        await page.click("#token-save")
                async with asyncio.timeout(15):  # the dashboard reads, images and the feed
                    while not await page.evaluate(DASHBOARD_WORKS):
                        await asyncio.sleep(0.2)
                        await page.evaluate("renderGallery()")
                await page.goto(f"http://127.0.0.1:{elsewhere.port}/")
                cookie = cookies[-1]
                assert cookie is not None and cookie.startswith(f"{SESSION_COOKIE}=")
                assert await _replay(base, cookie) == {
                    "GET /api/fleet": 401, "GET /api/images/1.jpg": 401,
                    "POST /api/login": 401, "POST /api/mission/end": 401, "/ws": 401}
                await page.goto(base + "/")  # back on the station: a command still works
                await page.fill("#start-delay", "2")
                await page.click("#btn-start")
                async with asyncio.timeout(10):
                    while await _commands(base) < (1 if login == "link" else 2):
                        await asyncio.sleep(0.2)
                await context.close()
            await browser.close()
    finally:
        drone.close()


async def _commands(base: str) -> int:
    async with aiohttp.ClientSession() as http, http.get(
            base + "/api/mission", headers={"Authorization": f"Bearer {TOKEN}"}) as resp:
        return len((await resp.json()).get("commands") or [])
