"""Headless Chromium (Debian package) drives the dashboard against a live test fleet.

Screenshots go to artifacts/browser/ (gitignored).
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import math
import re
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from companion.protocol import CommandReceived
from ground_station.app import create_app
from ground_station.config import GroundConfig
from ground_station.fake_drone import FakeDrone, fly_demo_fleet
from ground_station.keys import LINK
from ground_station.token import login_code
from tests.keys import TEST_COMMAND_KEY, TEST_COMMAND_PUB

CHROMIUM = Path("/usr/bin/chromium")
ARTIFACTS = Path(__file__).resolve().parents[2] / "artifacts" / "browser"
LAUNCH_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
KEY = b"browser-test-fleet-key-0000000"
TOKEN = "browser-test-token-0123456789"

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(
        not CHROMIUM.exists(), reason="needs Debian chromium: apt-get install chromium"
    ),
]


async def wait_js(page: Any, predicate: str, arg: Any = None, *, timeout_s: float) -> None:
    """Poll a JavaScript predicate from here: Playwright's wait_for_function evaluates its
    predicate with eval() in the page, which the dashboard's CSP (no 'unsafe-eval') refuses."""
    async with asyncio.timeout(timeout_s):
        while not await page.evaluate(predicate, arg):
            await asyncio.sleep(0.1)


EXPECTED_COLOURS = {"uav1": "#4aa3ff", "uav2": "#ffa657", "uav3": "#3fb950", "uav4": "#f778ba"}
"""The palette slots of ids ending in 1..4 (app.js PALETTE), whatever the arrival order."""

SPEC = """\
[mission]
name = "browser"
t_end = 600.0

[types.image]
utility = "red_image"
aggregation = "max"
weight = 1.0
per_sender = true
markovian = false
params = { alpha = 100.0, S = 0.1, f_max = 5.0, f_1 = 2.5 }
"""


async def tile_colours(page: Any) -> dict[str, str]:
    """Each tile's colour as the page drew it: tile, map dot and chart legend must agree."""
    return dict(await page.evaluate("""() => Object.fromEntries(
        [...document.querySelectorAll('.tile')].map((t) => [t.dataset.drone, t.dataset.color]))"""))


SCENE = """\
name = "browser"
[home]
lat_deg = 51.1
lon_deg = 17.0
alt_m = 120.0
[ground]
width_m = 300.0
height_m = 240.0
[[red_objects]]
east_m = 40.0
north_m = 30.0
radius_m = 8.0
[[red_objects]]
east_m = -50.0
north_m = -20.0
shape = "box"
width_m = 6.0
length_m = 12.0
[[targets]]
id = 7
east_m = 0.0
north_m = 60.0
"""

SERIES_DRAWN = """() => ['xi', 'delta', 'latency', 'loss'].every((k) =>
    [...document.querySelectorAll('.tile')].every((t) => state.series.some((p) =>
        p.drones && p.drones[t.dataset.drone] && typeof p.drones[t.dataset.drone][k] ===
        'number')))"""
"""Every drone has points in the ξ, Δ, latency and loss series (charts not empty)."""

LABEL_BOXES = """() => [...document.querySelectorAll('#map text.label')].map((t) => {
    const b = t.getBBox(); return [b.x, b.y, b.width, b.height]; })"""


def assert_labels_apart_and_inside(boxes: list[list[float]]) -> None:
    assert boxes
    for x, y, w, h in boxes:
        assert min(x, y) >= 0 and max(x + w, y + h) <= 300, (x, y, w, h)
    for i, a in enumerate(boxes):
        for b in boxes[i + 1:]:
            apart = (a[0] + a[2] <= b[0] or b[0] + b[2] <= a[0]
                     or a[1] + a[3] <= b[1] or b[1] + b[3] <= a[1])
            assert apart, (a, b)


REPORT_AXES = """async () => { const c = document.querySelector('#r-chart').dataset;
    const s = await (await fetch('/api/report',  // the page key, as report.js sends it
        { headers: { 'X-GS-Key': localStorage.getItem('gs-key') } })).json();
    return { y: c.yTicks, x: c.xTicks, most: Number(c.most), t_max: Number(c.tMax),
             now_most: Math.max(...Object.values(s.drones).flatMap((d) => d.utility)) }; }"""
"""The report chart's axis labels as drawn, with the largest value and time it drew them for,
and the largest value now (a bin only grows: the drawing may have had fewer images)."""


def check_report_axes(axes: dict[str, Any]) -> None:
    """Every label is its gridline's value: 0, then equal steps of 1, 2, 2.5 or 5 times a
    power of ten, up to the first at or above the largest value (`make demo`'s report once
    labelled a 0..6 axis in quarters 0 2 3 5 6)."""
    y = [float(v) for v in axes["y"].split()]
    steps = {round(b - a, 9) for a, b in itertools.pairwise(y)}
    assert y[0] == 0.0 and len(steps) == 1, axes
    step = steps.pop()
    assert round(step / 10 ** math.floor(math.log10(step)), 9) in (1, 2, 2.5, 5), axes
    assert 0 < axes["most"] <= axes["now_most"] and y[-2] < axes["most"] <= y[-1], axes
    x = [float(v) for v in axes["x"].split()]
    assert len(x) >= 2 and x[0] == 0.0 and x[-1] <= axes["t_max"] < 2 * x[-1] - x[-2], axes


async def check_map(page: Any) -> None:
    """The scene under the fleet: area, red objects, target, home, trails, a true scale bar,
    labels apart and inside the map, also when every drone is at one spot or in a corner."""
    svg = page.locator("#map")
    assert await svg.locator("rect.area").count() == 1
    assert await svg.locator(".red-object").count() == 2
    assert await svg.locator("rect.target").count() == 1
    assert await svg.locator("path.home").count() == 1
    assert "home" in await page.inner_text("#map-key")  # the symbols are explained
    # and so is a struck-through tile value (a newcomer met one with no word on it)
    assert "older than it should be" in await page.inner_text("#key")
    assert "line-through" in await page.evaluate(
        "() => getComputedStyle(document.querySelector('#key .stale-sample')).textDecoration")
    await wait_js(page, "() => document.querySelectorAll('#map polyline.trail').length === 4",
                  timeout_s=10.0)
    # the bar says as many metres as it is long: the area rect is 300 m wide
    bar_m, bar_px, area_px = await page.evaluate("""() => {
        const l = document.querySelector('#map .scalebar line');
        return [parseFloat(document.querySelector('#map .scalebar text').textContent),
                l.x2.baseVal.value - l.x1.baseVal.value,
                document.querySelector('#map rect.area').width.baseVal.value]; }""")
    assert bar_m in (10, 20, 50, 100) and abs(bar_px / area_px * 300.0 - bar_m) < 0.2
    assert_labels_apart_and_inside(await page.evaluate(LABEL_BOXES))
    for x, y in ((0.0, 0.0), (-150.0, 120.0), (150.0, -120.0)):
        boxes = await page.evaluate("""([x, y, boxes]) => {
            const saved = state.drones;
            state.drones = new Map([...saved].map(([k, d]) => [k, { ...d, x_m: x, y_m: y }]));
            renderMap();
            const out = eval_boxes();
            state.drones = saved; renderMap();
            return out; }""".replace("eval_boxes()", f"({LABEL_BOXES})()"), [x, y, None])
        assert len(boxes) == 4
        assert_labels_apart_and_inside(boxes)


async def _another_start(drone: FakeDrone, other_than: int) -> CommandReceived:
    async with asyncio.timeout(10):
        while True:
            for c in drone.commands:
                if c.command.name == "start" and c.command.command_id != other_than:
                    return c
            await asyncio.sleep(0.05)


async def test_dashboard_live_tiles_and_start_mission(
    tmp_path: Path, aiohttp_server: Callable[..., Any]
) -> None:
    playwright_api = pytest.importorskip("playwright.async_api")
    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC)
    scene = tmp_path / "scene.toml"
    scene.write_text(SCENE)
    config = GroundConfig(
        spec=spec,
        scene=scene,
        fleet_id=21,
        fleet_key=KEY,
        command_key=TEST_COMMAND_KEY,
        data_dir=tmp_path / "gs",
        mission="browser",
        udp_host="127.0.0.1",
        udp_port=0,
        report_interval_s=0.25,
        command_retry_s=0.3,
        fsync=False,
    )
    server = await aiohttp_server(create_app(config, token=TOKEN))
    ground = server.app[LINK].local_addr
    fleet: list[FakeDrone] = []
    flying = asyncio.create_task(
        fly_demo_fleet(
            ground,
            fleet_id=21,
            key=KEY,
            command_public_key=TEST_COMMAND_PUB,
            drones=4,
            duration_s=60.0,
            images_per_s=3.0,
            on_start=fleet.extend,
        )
    )
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    errors: list[str] = []
    try:
        async with playwright_api.async_playwright() as pw:
            browser = await pw.chromium.launch_persistent_context(
                str(tmp_path / "chromium-profile"),
                executable_path=str(CHROMIUM),
                args=LAUNCH_ARGS,
                headless=True,
                viewport={"width": 1400, "height": 900},
            )
            page = browser.pages[0] if browser.pages else await browser.new_page()
            page.on("pageerror", lambda exc: errors.append(str(exc)))
            # the dashboard itself must work under its own Content-Security-Policy
            page.on("console", lambda m: errors.append(m.text)
                    if "Content Security Policy" in m.text else None)
            # the one-time login link: exchanged for an HttpOnly cookie, then off the URL
            code = login_code(TOKEN, now=time.time())
            await page.goto(f"http://127.0.0.1:{server.port}/?login={code}")
            assert page.url == f"http://127.0.0.1:{server.port}/"
            assert await page.evaluate("document.cookie") == ""  # HttpOnly: not for scripts
            # tiles appear and keep updating from the live sender
            tile = page.locator('.tile[data-drone="uav2"]')
            await tile.wait_for(timeout=15_000)
            first = int(await tile.get_attribute("data-images") or 0)
            await wait_js(
                page,
                """n => Number(document.querySelector('.tile[data-drone="uav2"]')
                        .dataset.images) >= n + 3""",
                first,
                timeout_s=15.0,
            )
            assert await page.locator(".tile").count() == 4
            # a drone that says it runs no mission shows it (audit 12: a restarted
            # companion sat idle for a whole mission, its tile looking like the others)
            uav4 = next(d for d in fleet if d.drone_id == "uav4")
            uav4.send_status("running", info={"mission": "idle"})
            await wait_js(page, """() => document.querySelector(
                '.tile[data-drone="uav4"] .v-mode').textContent.includes('· mission idle')""",
                          timeout_s=10.0)
            assert "mission" not in await page.inner_text('.tile[data-drone="uav1"] .v-mode')
            # the spec's scale (alpha 100): high from 1 + 0.1·100 = 11, sent in the snapshot;
            # uav2 sees red (1 + 100·0.45 = 46): red border; uav1 (1 + 100·0.02 = 3.0, high
            # under the old fixed 3.0) and uav3 (object flag, no weight under red_image) not
            assert await page.evaluate("state.config.high_utility") == 11.0
            assert "high" in (await tile.get_attribute("class") or "")
            for calm in ("uav1", "uav3"):
                calm_class = await page.locator(f'.tile[data-drone="{calm}"]').get_attribute(
                    "class")
                assert "high" not in (calm_class or "")
            # colours follow the id, not the order drones were heard in, and survive a reload
            colours = await tile_colours(page)
            assert colours == EXPECTED_COLOURS
            await page.reload()
            await wait_js(page, "() => document.querySelectorAll('.tile').length === 4",
                          timeout_s=15.0)
            assert await tile_colours(page) == EXPECTED_COLOURS
            await wait_js(
                page,
                "() => document.querySelectorAll('#map circle.drone').length === 4",
                timeout_s=10.0,
            )
            await check_map(page)
            await page.wait_for_selector("#gallery figure", timeout=15_000)
            # the legend explains the numbers, with the threshold the spec gives
            key = await page.inner_text("#key")
            for term in ("U", "share", "ξ", "Δ", "fallback"):
                assert f"{term}\n" in key or key.startswith(term), (term, key)
            assert await page.inner_text("#key-high") == "U 11.00"
            # U of a version: the full image's weight times its quality (eq. 4.33)
            assert ("1 plain … 101 best (spec spec.toml), × the version sent (half size 0.5)"
                    in key)
            # each gallery image says why it was sent; the best first: uav2's red images
            await wait_js(page, "() => document.querySelector('#gallery .why') !== null",
                          timeout_s=10.0)
            why = (await page.inner_text("#gallery figure:first-child .why")).replace("\xa0", " ")
            assert re.fullmatch(
                r"why sent: U 46\.00 \(red 45 %\) · single version · \d{1,3} % of link", why
            ), why
            await page.screenshot(path=str(ARTIFACTS / "dashboard_live.png"), full_page=True)
            # above the fold at 1400x900: every tile, the link charts, map, the gallery's start
            fold = await page.evaluate("""() => {
                scrollTo(0, 0);
                const r = (s) => document.querySelector(s).getBoundingClientRect();
                return { tiles: Math.max(...[...document.querySelectorAll('.tile')]
                           .map((t) => t.getBoundingClientRect().bottom)),
                         link: r('.link').bottom, map: r('#map').bottom,
                         gallery: r('#gallery figure').top,
                         width: document.documentElement.scrollWidth,
                         clipped: [...document.querySelectorAll('.tile')].filter(
                           (t) => t.querySelector('table').scrollWidth > t.clientWidth)
                           .map((t) => t.dataset.drone) }; }""")
            await page.screenshot(path=str(ARTIFACTS / "dashboard_1400x900.png"))
            assert max(fold["tiles"], fold["link"], fold["map"]) <= 900, fold
            assert fold["gallery"] <= 900 - 120, fold  # at least a row's picture shows
            assert fold["width"] <= 1400, fold  # no sideways scrolling
            assert fold["clipped"] == [], fold  # no tile cuts its table off

            # start mission: the COMMAND reaches every drone, which acks it
            await page.fill("#start-delay", "12")  # room for a loaded CI machine
            clicked = time.time()
            await page.click("#btn-start")
            commands = await asyncio.gather(*(d.wait_command(timeout=10) for d in fleet))
            for received in commands:
                assert received.command.name == "start"
                assert clicked + 11.0 < received.command.t_exec < time.time() + 12.0
            await page.wait_for_selector("#toast:not(.hidden)", timeout=5_000)
            assert "start mission: command #" in await page.inner_text("#toast")
            await wait_js(
                page,
                "() => document.querySelector('#mission-info').innerText.includes('acked 4/4')",
                timeout_s=10.0,
            )
            assert await page.inner_text("#mission-phase") == "scheduled"
            await page.screenshot(path=str(ARTIFACTS / "dashboard_mission.png"), full_page=True)
            # end mission (now) while the start waits: it cancels the start, which the
            # command list says; the next start is the one that runs
            await page.fill("#start-delay", "")
            await page.click("#btn-end")
            await wait_js(page, "() => document.querySelector('#mission-info').innerText"
                          ".includes('superseded by #')", timeout_s=10.0)
            assert await page.inner_text("#mission-phase") == "idle"
            await page.fill("#start-delay", "12")
            clicked = time.time()
            await page.click("#btn-start")
            cancelled = commands[0].command.command_id
            commands = await asyncio.gather(*(_another_start(d, cancelled) for d in fleet))
            assert all(clicked + 11.0 < c.command.t_exec for c in commands)
            # once the start time passed: the badge follows (issue 11, symptom 6) and every
            # drone's result shows
            start_line = f"#mission-info [data-command='{commands[0].command.command_id}']"
            await wait_js(
                page,
                f"() => document.querySelector(\"{start_line}\")?.innerText.includes('done 4/4')",
                timeout_s=25.0,
            )
            await wait_js(  # within one badge refresh (0.5 s) of t_exec
                page,
                "() => document.querySelector('#mission-phase').innerText === 'running'",
                timeout_s=2.0,
            )
            assert time.time() >= commands[0].command.t_exec
            # the link charts have something to draw: ξ, Δ, latency and loss per drone
            await wait_js(page, SERIES_DRAWN, timeout_s=15.0)
            # a clean run: every drone heard all along, no link-lost alert, none listed
            alerts = await page.evaluate(
                "() => state.alerts.filter((a) => a.kind === 'link').map((a) => a.text)")
            assert alerts == [], alerts
            assert "link lost" not in await page.inner_text("#alerts")
            await page.screenshot(path=str(ARTIFACTS / "dashboard_running.png"))
            # the end-of-mission report: utility over time per drone, in the drones' colours
            await page.click("#report-link")
            legend: dict[str, str] = {}
            deadline = time.monotonic() + 15.0  # the first images of the run being stored
            while True:
                await wait_js(page, "() => document.body.dataset.loaded === '1'",
                              timeout_s=15.0)
                legend = dict(await page.evaluate("""() => [...document.querySelectorAll(
                    '#r-legend .lg')].map((e) => [e.dataset.drone, e.dataset.color])"""))
                if len(legend) == 4 or time.monotonic() > deadline:
                    break
                await asyncio.sleep(0.5)
                await page.reload()
            assert legend == EXPECTED_COLOURS
            check_report_axes(await page.evaluate(REPORT_AXES))
            await wait_js(page, "() => document.querySelector('#r-png').naturalWidth > 0",
                          timeout_s=15.0)
            assert (tmp_path / "gs" / "missions" / "browser" / "utility.png").exists()
            await page.screenshot(path=str(ARTIFACTS / "report.png"), full_page=True)
            await browser.close()
    finally:
        flying.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await flying
    assert errors == []
