"""The aiohttp application factory: routes, state, the token middleware, cleanup contexts.

``create_app(config)`` wires everything (aiohttp "app factory"); ``web.run_app`` runs it and
tests import the same factory. The UDP endpoint and the storage are one-``yield`` cleanup
contexts, WebSockets sit in a ``WeakSet`` closed at shutdown, and one middleware checks the
control token. The read API and the WebSocket are here; the token middleware and the login in
:mod:`ground_station.auth`, the control API in :mod:`ground_station.control_api`.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import time
from collections.abc import AsyncIterator, Callable
from typing import Any

from aiohttp import WSMsgType, web

from companion.admission import ConnectionGate
from ground_station.auth import LOGIN_CODES, STATIC_DIR, api_login, index, token_middleware
from ground_station.broadcast import Broadcaster
from ground_station.config import GroundConfig
from ground_station.control_api import (
    api_end,
    api_params,
    api_report,
    api_reset_reports,
    api_start,
)
from ground_station.fleet import RATE_WINDOW_S, FleetView, LatestImage
from ground_station.host_guard import host_guard, origin_guard
from ground_station.http_guard import add_security_headers, json_reply, same_origin
from ground_station.keys import (
    BROADCASTER,
    CLOCK,
    CONFIG,
    FLEET,
    IMAGE_UTILITY,
    LATEST_JPEG,
    LINK,
    MISSIONS,
    STORAGE,
    TOKEN,
    WEBSOCKETS,
)
from ground_station.medium_hint import StatusUnheard
from ground_station.missions import MissionManager
from ground_station.receiver import GroundLink
from ground_station.scene_map import load_scene_map
from ground_station.storage import ImageRow, Storage
from ground_station.store_service import StorageService
from ground_station.token import LoginCodes, ensure_token
from ground_station.utility import image_utility_from_spec
from ground_station.ws_guard import (
    close_all,
    refusal,
    refusal_text,
    release_unsent,
    send_or_drop,
    websocket_gate,
)

__all__ = ["STATIC_DIR", "create_app"]

log = logging.getLogger(__name__)

SCENE_MAP: web.AppKey[dict[str, Any] | None] = web.AppKey("scene_map")
WS_GATE: web.AppKey[ConnectionGate] = web.AppKey("ws_gate")


# -- read API ------------------------------------------------------------------------------
async def api_stats(request: web.Request) -> web.Response:
    app = request.app
    now = app[CLOCK]()
    return json_reply(
        {"station": app[CONFIG].station_id, "mission": app[CONFIG].mission}
        | app[LINK].stats(now=now)
    )


async def api_fleet(request: web.Request) -> web.Response:
    app = request.app
    now = app[CLOCK]()
    snap = app[FLEET].snapshot(now=now)
    snap["mission"] = app[MISSIONS].state(now=now)
    snap["config"] = {"station_id": app[CONFIG].station_id, "alpha": app[CONFIG].alpha} | (
        _dashboard_config(app))
    return json_reply(snap)


def _dashboard_config(app: web.Application) -> dict[str, Any]:
    """What the page needs to read utilities: mission name and the spec's utility scale."""
    config = app[CONFIG]
    gain = app[IMAGE_UTILITY].max_gain()
    return {
        "mission": config.mission,
        "high_utility": app[FLEET].high_utility,
        "scene": app[SCENE_MAP],
        "utility_scale": {
            "plain": 1.0,
            "max": 1.0 + gain,
            "fraction": None if config.high_utility is not None else config.high_utility_fraction,
            "source": (f"spec {config.spec.name}" if config.spec is not None
                       else f"alpha {config.alpha:g}"),
        },
    }


async def api_mission(request: web.Request) -> web.Response:
    app = request.app
    return json_reply(app[MISSIONS].state(now=app[CLOCK]()))


async def api_missions(request: web.Request) -> web.Response:
    return json_reply(await request.app[STORAGE].read(lambda s: s.missions()))


def _image_json(row: ImageRow) -> dict[str, Any]:
    return row.as_json() | {"url": f"/api/images/{row.id}.jpg"}


_OBJECT_FILTER: dict[str, bool | None] = {
    "": None, "any": None, "true": True, "1": True, "yes": True,
    "false": False, "0": False, "no": False}
"""``/api/images?object=``: the gallery's three choices, and 1/0, yes/no."""


async def api_images(request: web.Request) -> web.Response:
    """Gallery: highest-utility images of a mission, filterable by drone and object flag."""
    app = request.app
    q = request.query
    mission = q.get("mission", app[CONFIG].mission)
    drone = q.get("drone") or None
    obj = q.get("object", "")
    order = q.get("order", "utility")
    # a mistyped value was read as the default (order) or as false (object), silently
    if obj not in _OBJECT_FILTER:
        return json_reply({"error": f"object must be true, false or any, got {obj!r}"},
                          status=400)
    if order not in ("utility", "time"):
        return json_reply({"error": f"order must be utility or time, got {order!r}"},
                          status=400)
    object_only = _OBJECT_FILTER[obj]
    try:
        limit = int(q.get("limit", "24"))
    except ValueError:
        return json_reply({"error": "limit must be an integer"}, status=400)

    senders = list(app[FLEET].drones)

    def query(s: Storage) -> list[dict[str, Any]]:
        rows = s.images(mission, sender=drone, object_only=object_only, order=order, limit=limit)
        # "why sent": the sender's share of the link when the image arrived
        return [_image_json(r) | {"window_share": s.window_share(
            mission, r, senders, window_s=RATE_WINDOW_S)} for r in rows]

    images = await app[STORAGE].read(query)
    return json_reply({"mission": mission, "images": images, "window_s": RATE_WINDOW_S})


async def api_image_file(request: web.Request) -> web.StreamResponse:
    app = request.app
    text = request.match_info["image_id"]
    if not (text.isascii() and text.isdigit() and len(text) <= 18):  # SQLite ids are int64
        raise web.HTTPNotFound()
    image_id = int(text)
    row = await app[STORAGE].read(lambda s: s.image(image_id))
    if row is None or row.path is None:
        raise web.HTTPNotFound()
    root = app[CONFIG].data_dir.resolve()
    path = (root / row.path).resolve()
    if not path.is_relative_to(root):
        raise web.HTTPNotFound()
    return web.FileResponse(path, headers={"Content-Type": "image/jpeg"})


async def api_latest_jpeg(request: web.Request) -> web.Response:
    payload = request.app[LATEST_JPEG].get(request.match_info["drone"])
    if payload is None:
        raise web.HTTPNotFound()
    return web.Response(
        body=payload, content_type="image/jpeg", headers={"Cache-Control": "no-store"}
    )


async def api_alerts(request: web.Request) -> web.Response:
    app = request.app
    mission = request.query.get("mission", app[CONFIG].mission)
    stored = await app[STORAGE].read(lambda s: s.alerts(mission))
    return json_reply({"alerts": stored})


async def api_telemetry(request: web.Request) -> web.Response:
    app = request.app
    mission = request.query.get("mission", app[CONFIG].mission)
    drone = request.query.get("drone") or None
    rows = await app[STORAGE].read(lambda s: s.telemetry(mission, sender=drone))
    return json_reply({"messages": rows})


# -- WebSocket -----------------------------------------------------------------------------
async def websocket(request: web.Request) -> web.WebSocketResponse:
    """Live updates: a snapshot first, then drone/status/alert/tick/mission events."""
    app = request.app
    config = app[CONFIG]
    if "Origin" in request.headers and not same_origin(request):
        # a page elsewhere must not read the live feed with this browser's cookie
        raise web.HTTPForbidden(text="cross-origin WebSocket refused")
    gate, remote = app[WS_GATE], request.remote or "?"
    refused = gate.admit(remote)
    if refused is not None:  # idle sockets must not take every HTTP connection
        if refused.worth_logging:
            log.warning("%s (%d refused so far)", refusal_text(refused), refused.refused)
        raise refusal(refused)
    try:
        return await _live_feed(request, send_timeout_s=config.ws_send_timeout_s)
    finally:
        gate.release(remote)


async def _live_feed(request: web.Request, *, send_timeout_s: float) -> web.WebSocketResponse:
    app = request.app
    ws = web.WebSocketResponse(heartbeat=app[CONFIG].ws_heartbeat_s,
                               max_msg_size=4096)  # a client only ever sends "ping"
    try:
        await ws.prepare(request)
    except web.HTTPBadRequest:  # aiohttp's text quotes the request's headers
        raise web.HTTPBadRequest(text="400 Bad Request: not a WebSocket handshake\n") from None
    app[WEBSOCKETS][ws] = request
    client = app[BROADCASTER].register()
    now = app[CLOCK]()
    snapshot = app[FLEET].snapshot(now=now)
    snapshot["mission"] = app[MISSIONS].state(now=now)
    snapshot["config"] = _dashboard_config(app)
    first = json.dumps({"kind": "snapshot", **snapshot}, default=str)

    async def writer() -> None:  # a client that stops reading is dropped, not waited for
        text = first
        while await send_or_drop(request, ws, text, timeout_s=send_timeout_s):
            text = await client.queue.get()

    task = asyncio.create_task(writer(), name="gs-ws-writer")
    try:
        async for msg in ws:
            if msg.type is WSMsgType.TEXT and msg.data == "ping":
                client.put(json.dumps({"kind": "pong", "t": app[CLOCK]()}))
            elif msg.type is WSMsgType.ERROR:
                break
    finally:
        app[BROADCASTER].unregister(client)
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError, ConnectionError):
            await task
        app[WEBSOCKETS].pop(ws, None)
        release_unsent(request)
    return ws


async def close_websockets(app: web.Application) -> None:
    feeds = app[WEBSOCKETS]
    await close_all(feeds, timeout_s=1.0)


# -- cleanup contexts ----------------------------------------------------------------------
async def storage_ctx(app: web.Application) -> AsyncIterator[None]:
    config = app[CONFIG]

    def on_batch(items: Any, result: Any) -> None:
        link = app.get(LINK)
        if link is not None:
            link.on_storage_batch(items, result)

    service = StorageService(
        config.data_dir, clock=app[CLOCK], fsync=config.fsync, on_batch=on_batch
    )
    await service.open()
    app[STORAGE] = service
    try:
        yield
    finally:
        await service.close()
        s = service.stats()  # the one line a stop leaves: what this run kept, and did not
        log.info("stopped: %d messages stored (%d images), %d not stored, %d refused",
                 s["written"] - s["not_stored"], s["images_stored"], s["not_stored"],
                 s["refused"])


async def link_ctx(app: web.Application) -> AsyncIterator[None]:
    """The UDP endpoint; before it opens, tiles are seeded from storage (restart resumes)."""
    config = app[CONFIG]
    fleet = app[FLEET]
    rows = await app[STORAGE].read(lambda s: s.latest_images(config.mission))
    for row in rows:
        state = fleet.restore(row.sender, last_heard=row.t_rcv)
        state.latest_image = LatestImage(
            image_id=row.id,
            seq=row.seq,
            t_gen=row.t_gen,
            t_rcv=row.t_rcv,
            size=row.size,
            utility=row.utility,
            red=row.red,
            object=row.object,
            high=fleet.is_high(row.utility),
        )
        if row.path is not None:
            path = config.data_dir / row.path
            with contextlib.suppress(OSError):
                app[LATEST_JPEG][row.sender] = await asyncio.to_thread(path.read_bytes)
    link = GroundLink(
        config=config,
        clock=app[CLOCK],
        fleet=fleet,
        missions=app[MISSIONS],
        storage=app[STORAGE],
        broadcaster=app[BROADCASTER],
        image_utility=app[IMAGE_UTILITY],
        latest_jpeg=app[LATEST_JPEG],
    )
    host, port = await link.open()
    app[LINK] = link
    log.info("receiving fleet %d on udp://%s:%d", config.fleet_id, host, port)
    mirror = None
    if config.mavlink_out or config.mavlink_listen:  # MAVLink 2 fleet mirror
        from ground_station.mavlink_out import open_mavlink_out  # pymavlink only when used

        mirror = await open_mavlink_out(config, app[CLOCK])
        if mirror is not None:
            link.data_listeners.append(mirror.on_data)
    try:
        yield
    finally:
        link.close()
        if mirror is not None:
            mirror.close()


def create_app(
    config: GroundConfig, *, clock: Callable[[], float] = time.time, token: str | None = None
) -> web.Application:
    """Build the ground-station app; the token is read or created under ``config.data_dir``."""
    guard = host_guard((*config.allowed_hosts, config.http_host))  # DNS rebinding
    app = web.Application(middlewares=[guard, token_middleware, origin_guard()],
                          client_max_size=1 << 20)
    app[CONFIG] = config
    app[CLOCK] = clock
    app[TOKEN] = token if token is not None else ensure_token(config.token_path)[0]
    app[LOGIN_CODES] = LoginCodes(app[TOKEN])
    app[IMAGE_UTILITY] = image_utility_from_spec(config.spec, alpha=config.alpha)
    high_utility = (config.high_utility if config.high_utility is not None
                    else app[IMAGE_UTILITY].high_threshold(config.high_utility_fraction))
    app[FLEET] = FleetView(high_utility=high_utility, link_lost_s=config.link_lost_s,
                           clock_tolerance_s=config.clock_tolerance_s)
    # a fleet sharing its status on a medium the station does not hear: told, not silent
    app[FLEET].status_unheard = StatusUnheard(medium=config.shared_medium)
    scene = load_scene_map(config.scene) if config.scene is not None else None
    if scene is not None:  # the map's frame: east/north metres from the scene's home
        app[FLEET].set_origin(scene["home"]["lat_deg"], scene["home"]["lon_deg"])
    app[SCENE_MAP] = scene
    app[MISSIONS] = MissionManager(
        retry_s=config.command_retry_s,
        reply_timeout_s=config.command_reply_timeout_s,
        command_ttl_s=config.command_ttl_s,
        first_command_id=int(clock() * 10) % (2**31)
    )
    app[BROADCASTER] = Broadcaster(queue_size=config.ws_queue_size)
    app[LATEST_JPEG] = {}
    app[WEBSOCKETS] = {}
    app[WS_GATE] = websocket_gate(config.http_max_connections, config.ws_max_per_client)
    app.cleanup_ctx.append(storage_ctx)
    app.cleanup_ctx.append(link_ctx)
    app.on_shutdown.append(close_websockets)
    app.on_response_prepare.append(add_security_headers)
    app.router.add_get("/", index)
    app.router.add_static("/static/", STATIC_DIR, append_version=True)
    app.router.add_get("/ws", websocket)
    app.router.add_get("/api/stats", api_stats)
    app.router.add_get("/api/fleet", api_fleet)
    app.router.add_get("/api/mission", api_mission)
    app.router.add_get("/api/missions", api_missions)
    app.router.add_get("/api/images", api_images)
    app.router.add_get(r"/api/images/{image_id}.jpg", api_image_file)
    app.router.add_get("/api/drones/{drone}/latest.jpg", api_latest_jpeg)
    app.router.add_get("/api/alerts", api_alerts)
    app.router.add_get("/api/telemetry", api_telemetry)
    app.router.add_post("/api/login", api_login)
    app.router.add_post("/api/mission/start", api_start)
    app.router.add_post("/api/mission/end", api_end)
    app.router.add_post("/api/mission/params", api_params)
    app.router.add_post("/api/mission/report", api_report)
    app.router.add_post("/api/mission/reports/reset", api_reset_reports)
    from ground_station.report_page import add_report_routes  # the end-of-mission report

    add_report_routes(app, static_dir=STATIC_DIR)
    return app
