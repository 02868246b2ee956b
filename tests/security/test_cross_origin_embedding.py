"""A page on another port of the station's host embeds the station's answers (2026-11-25).

The session cookie is ``SameSite=Strict``, but a site is a scheme and a host: a page served
from ``http://127.0.0.1:OTHER`` (any local program's web page, another user's on a shared
computer) is same-site with the station on ``http://127.0.0.1:8080``, so the browser sends
the operator's cookie with that page's ``<img src=".../api/images/1.jpg">``. Before
``Cross-Origin-Resource-Policy: same-origin`` the image loaded: the page learnt which images
and drones exist, and their sizes. Real headless Chromium, logged in as the operator is.
The URLs carry the page key as the dashboard's own do (``token.page_key``, which since the
same day the cookie needs and such a page lacks): this checks CORP on its own.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from aiohttp import web

from ground_station.app import create_app
from ground_station.config import GroundConfig
from ground_station.fake_drone import FakeDrone, synthetic_jpeg
from ground_station.keys import LINK
from ground_station.token import login_code, page_key
from tests.keys import TEST_COMMAND_KEY

CHROMIUM = Path("/usr/bin/chromium")
KEY = b"corp-test-fleet-key-00000000000"
TOKEN = "corp-test-token-0123456789"

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(not CHROMIUM.exists(),
                       reason="needs Debian chromium: apt-get install chromium"),
]

PROBE = """async (urls) => Promise.all(urls.map(url => new Promise(done => {
  const img = new Image();
  img.onload = () => done(`loaded ${img.naturalWidth}x${img.naturalHeight}`);
  img.onerror = () => done("blocked");
  img.src = url;
})))"""


async def test_a_same_site_page_cannot_embed_the_fleets_images(
        tmp_path: Path, aiohttp_server: Callable[..., Any]) -> None:
    playwright_api = pytest.importorskip("playwright.async_api")
    config = GroundConfig(fleet_id=5, fleet_key=KEY, command_key=TEST_COMMAND_KEY,
                          data_dir=tmp_path / "gs", mission="corp", udp_host="127.0.0.1",
                          udp_port=0, fsync=False)
    station = await aiohttp_server(create_app(config, token=TOKEN))
    drone = FakeDrone("uav1", fleet_id=5, key=KEY, ground=station.app[LINK].local_addr)
    await drone.open()
    drone.send_image(synthetic_jpeg(1, red=0.3, label="uav1"), data={"red": 0.3})

    async def other_page(request: web.Request) -> web.Response:
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
            page = await browser.new_page()
            await page.goto(f"{base}/?login={login_code(TOKEN, now=time.time())}")
            key = page_key(TOKEN)
            urls = [f"{base}/api/images/1.jpg?key={key}",
                    f"{base}/api/drones/uav1/latest.jpg?key={key}",
                    f"{base}/api/report.png?mission=corp&key={key}"]
            async with asyncio.timeout(15):  # the operator's own page shows them
                while (mine := await page.evaluate(PROBE, urls))[0] == "blocked":
                    await asyncio.sleep(0.2)
            assert all(r.startswith("loaded ") for r in mine), mine
            await page.goto(f"http://127.0.0.1:{elsewhere.port}/")
            assert await page.evaluate(PROBE, urls) == ["blocked"] * len(urls)
            await browser.close()
    finally:
        drone.close()
