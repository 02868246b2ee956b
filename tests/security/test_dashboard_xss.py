"""Hostile strings from the air in the real dashboard (headless Chromium): drone ids, alert
texts (STATUSTEXT), flight modes and image metadata are shown as text, never parsed as HTML.
The page's CSP would stop an injected handler from running; this checks the markup itself, so
the escaping does not rest on the CSP alone."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from ground_station.app import create_app
from ground_station.config import GroundConfig
from ground_station.fake_drone import FakeDrone, synthetic_jpeg
from ground_station.keys import LINK
from ground_station.token import login_code
from tests.keys import TEST_COMMAND_KEY, TEST_COMMAND_PUB

CHROMIUM = Path("/usr/bin/chromium")
KEY = b"xss-test-fleet-key-000000000000"
TOKEN = "xss-test-token-0123456789"
HOSTILE_IDS = ['<img src=x onerror=alert(1)>', '"><b class=pwn>1', "'><svg onload=x>"]
HOSTILE_TEXT = '<img src=y onerror="window.pwned=1"><b class=pwn>alert</b>'

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(not CHROMIUM.exists(),
                       reason="needs Debian chromium: apt-get install chromium"),
]

INJECTED = """() => document.querySelectorAll(
  '.pwn, img[src="x"], img[src="y"], [onerror], [onload]').length"""


async def _fly(drones: list[FakeDrone]) -> None:
    jpeg = synthetic_jpeg(0, red=0.3, label="x")
    while True:
        for drone in drones:
            geo = {"lat": 51.1, "lon": 17.0, "alt": 40.0, "yaw_deg": 10.0}
            drone.send_image(jpeg, data={"red": 0.3, "object": True, "note": HOSTILE_TEXT,
                                         **geo})
            drone.send_telemetry("position", geo)
            drone.send_status("running", info={
                "mode": HOSTILE_TEXT[:40], "armed": True, "gps_fix": 3,
                "statustext": HOSTILE_TEXT, "severity": 2})
        await asyncio.sleep(0.3)


async def test_hostile_strings_are_text_in_the_dashboard(
        tmp_path: Path, aiohttp_server: Callable[..., Any]) -> None:
    playwright_api = pytest.importorskip("playwright.async_api")
    config = GroundConfig(fleet_id=23, fleet_key=KEY, command_key=TEST_COMMAND_KEY,
                          data_dir=tmp_path / "gs", mission="xss", udp_host="127.0.0.1",
                          udp_port=0, report_interval_s=0.25, fsync=False)
    server = await aiohttp_server(create_app(config, token=TOKEN))
    ground = server.app[LINK].local_addr
    drones = [FakeDrone(d, fleet_id=23, key=KEY, ground=ground,
                        command_public_key=TEST_COMMAND_PUB) for d in HOSTILE_IDS]
    for drone in drones:
        await drone.open()
    flying = asyncio.create_task(_fly(drones))
    try:
        async with playwright_api.async_playwright() as pw:
            browser = await pw.chromium.launch(executable_path=str(CHROMIUM), headless=True,
                                               args=["--no-sandbox", "--disable-gpu"])
            page = await browser.new_page()
            await page.goto(f"http://127.0.0.1:{server.port}/?login="
                            f"{login_code(TOKEN, now=time.time())}")
            async with asyncio.timeout(20):
                while await page.locator(".tile").count() < len(HOSTILE_IDS) or \
                        await page.locator("#gallery figure").count() == 0 or \
                        "alert" not in await page.inner_text("#alerts"):
                    await asyncio.sleep(0.2)
                    if await page.locator("#gallery figure").count() == 0:
                        await page.evaluate("renderGallery()")
            headers = await page.locator(".tile header b").all_inner_texts()
            assert sorted(headers) == sorted(HOSTILE_IDS)
            assert HOSTILE_TEXT in await page.inner_text("#alerts")
            gallery = await page.inner_text("#gallery")
            assert any(d in gallery for d in HOSTILE_IDS)
            assert await page.evaluate(INJECTED) == 0
            assert await page.evaluate("() => window.pwned === undefined")
            await browser.close()
    finally:
        flying.cancel()
        for drone in drones:
            drone.close()
