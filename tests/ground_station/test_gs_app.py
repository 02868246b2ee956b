"""The aiohttp app through its public entry points: token, API, WebSocket, full disk."""

from __future__ import annotations

import errno
import os
import stat
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from aiohttp import WSMsgType
from aiohttp.test_utils import TestClient

from companion.protocol import Encoder
from ground_station.app import create_app
from ground_station.config import GroundConfig
from ground_station.keys import LINK, STORAGE, TOKEN
from ground_station.storage import Storage
from ground_station.token import page_key, session_value
from utility_specs.message import Message

KEY = b"ground-station-test-fleet-key"  # as in conftest.gs_config
TOKEN_VALUE = "test-token-0123456789"  # as in conftest.gs_client


def auth() -> dict[str, str]:
    return {"Authorization": f"Bearer {TOKEN_VALUE}"}


ADDR = ("127.0.0.1", 40001)


class Clock:
    def __init__(self, t: float) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def feed(
    client: TestClient[Any, Any],
    encoder: Encoder,
    seq: int,
    *,
    now: float,
    msg_type: str = "image",
    payload: bytes = b"",
    **data: Any,
) -> None:
    """Deliver one message's datagrams straight into the app's UDP protocol."""
    m = Message(
        sender=encoder.sender, seq=seq, type=msg_type, t_gen=now - 0.1, size=len(payload), data=data
    )
    link = client.server.app[LINK]
    for datagram in encoder.fragment(m, payload, now):
        link.datagram_received(datagram, ADDR)


async def test_control_needs_token_reads_need_it_unless_public(
    gs_client: TestClient[Any, Any],
    gs_config: GroundConfig,
    aiohttp_client: Callable[..., Any],
) -> None:
    assert (await gs_client.post("/api/mission/start", json={})).status == 401
    assert (await gs_client.get("/api/fleet")).status == 401
    bad = {"Authorization": "Bearer nope"}
    assert (await gs_client.get("/api/fleet", headers=bad)).status == 401
    assert (await gs_client.get("/api/fleet", headers=auth())).status == 200
    assert (await gs_client.get("/")).status == 200  # the page itself holds no data
    # the dashboard's session (cookie and page key) opens reads, control routes only from
    # this origin (no CSRF; tests/ground_station/test_http_security.py); the raw token is no
    # cookie, and the cookie alone opens nothing
    cookie = {"Cookie": f"gs_session={session_value(TOKEN_VALUE)}",
              "X-GS-Key": page_key(TOKEN_VALUE)}
    raw = {"Cookie": f"gs_session={TOKEN_VALUE}", "X-GS-Key": page_key(TOKEN_VALUE)}
    assert (await gs_client.get("/api/fleet", headers=raw)).status == 401
    assert (await gs_client.get("/api/fleet", headers=cookie)).status == 200
    assert (await gs_client.get("/api/fleet", headers={"Cookie": cookie["Cookie"]})).status == 401
    assert (await gs_client.post("/api/mission/start", json={}, headers=cookie)).status == 401
    public = gs_config.with_overrides(public_read=True, data_dir=gs_config.data_dir / "p")
    client: TestClient[Any, Any] = await aiohttp_client(create_app(public, token="x" * 20))
    assert (await client.get("/api/fleet")).status == 200
    assert (await client.post("/api/mission/start", json={})).status == 401
    # a token in the URL is refused (it would end up in logs and histories); a header works
    assert (
        await client.post("/api/mission/start", json={}, params={"token": "x" * 20})
    ).status == 401
    assert (
        await client.post("/api/mission/start", json={},
                          headers={"Authorization": "Bearer " + "x" * 20})
    ).status == 200


async def test_token_generated_once_with_0600(
    gs_config: GroundConfig, aiohttp_client: Callable[..., Any]
) -> None:
    client: TestClient[Any, Any] = await aiohttp_client(create_app(gs_config))
    token = client.server.app[TOKEN]
    path = gs_config.token_path
    assert path.read_text().strip() == token and len(token) >= 24
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    again: TestClient[Any, Any] = await aiohttp_client(create_app(gs_config))
    assert again.server.app[TOKEN] == token


async def test_websocket_snapshot_then_tile_updates(gs_client: TestClient[Any, Any]) -> None:
    ws = await gs_client.ws_connect("/ws", headers=auth())
    first = await ws.receive_json(timeout=5)
    assert first["kind"] == "snapshot" and first["drones"] == []
    enc = Encoder(7, "uav1", KEY)
    import time

    feed(gs_client, enc, 1, now=time.time(), payload=b"\xff\xd8" + b"x" * 3000, red=0.5)
    msg = await ws.receive_json(timeout=5)
    while msg["kind"] != "drone":
        msg = await ws.receive_json(timeout=5)
    tile = msg["drone"]
    assert tile["drone"] == "uav1" and tile["images"] == 1
    assert tile["latest_image"]["utility"] == pytest.approx(6.0)  # 1 + 10·0.5 (eq. 7.1)
    assert tile["latest_image"]["high"] is True
    jpeg = await gs_client.get("/api/drones/uav1/latest.jpg", headers=auth())
    assert jpeg.content_type == "image/jpeg" and len(await jpeg.read()) == 3002
    await ws.close()
    assert (await ws.receive()).type in (WSMsgType.CLOSED, WSMsgType.CLOSE)


async def test_full_disk_alerts_and_telemetry_keeps_flowing(
    gs_client: TestClient[Any, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    def full(self: Storage, relpath: Path, payload: bytes) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(Storage, "_write_file", full)
    import time

    enc = Encoder(7, "uav1", KEY)
    feed(gs_client, enc, 1, now=time.time(), payload=b"j" * 5000, red=0.1)
    feed(gs_client, enc, 2, now=time.time(), msg_type="battery", level=0.42)
    await gs_client.server.app[STORAGE].flush()
    fleet = await (await gs_client.get("/api/fleet", headers=auth())).json()
    storage_alerts = [a for a in fleet["alerts"] if a["kind"] == "storage"]
    assert len(storage_alerts) == 1
    assert "image uav1/1 not stored: disk full" in storage_alerts[0]["text"]
    assert fleet["drones"][0]["battery"] == 0.42
    telemetry = await (await gs_client.get("/api/telemetry", headers=auth())).json()
    assert [m["type"] for m in telemetry["messages"]] == ["battery", "image"]
    stats = await (await gs_client.get("/api/stats", headers=auth())).json()
    assert stats["storage"]["errors"] == 1 and stats["link"]["storage_errors"] == 1
    # the alert itself is stored as well
    await gs_client.server.app[STORAGE].flush()
    stored = await (await gs_client.get("/api/alerts", headers=auth())).json()
    assert any(a["kind"] == "storage" for a in stored["alerts"])


async def test_mission_api_exact_times_and_validation(
    gs_config: GroundConfig, aiohttp_client: Callable[..., Any]
) -> None:
    clock = Clock(1_700_000_000.0)
    client: TestClient[Any, Any] = await aiohttp_client(
        create_app(gs_config, token="t" * 20, clock=clock)
    )
    h = {"Authorization": "Bearer " + "t" * 20}
    r = await client.post("/api/mission/start", json={"when": "in 5 s"}, headers=h)
    body = await r.json()
    assert r.status == 200 and body["command"]["t_exec"] == 1_700_000_005.0
    assert body["mission"]["phase"] == "scheduled"
    r = await client.post(
        "/api/mission/params", json={"params": "alpha=10, mcts_iterations=300"}, headers=h
    )
    body = await r.json()
    assert body["command"]["name"] == "set_params"
    assert body["command"]["args"] == {"alpha": 10, "mcts_iterations": 300}
    r = await client.post("/api/mission/end", json={"delay_s": 60}, headers=h)
    assert (await r.json())["command"]["t_exec"] == 1_700_000_060.0
    # the alerts say when relative to their own time, not in the station's clock format
    await client.server.app[STORAGE].flush()
    alerts = (await (await client.get("/api/alerts", headers=h)).json())["alerts"]
    said = [a["text"] for a in alerts if a["kind"] == "mission"]
    assert "start in 5 s: sent to 0 drone(s)" in said
    assert "end in 60 s: sent to 0 drone(s)" in said
    for bad in ({"when": "whenever"}, {"delay_s": -1}, {"t_exec": "x"}):
        r = await client.post("/api/mission/start", json=bad, headers=h)
        assert r.status == 400 and "error" in await r.json()
    r = await client.post("/api/mission/params", json={"params": {}}, headers=h)
    assert r.status == 400
    r = await client.post("/api/mission/start", data=b"not json", headers=h)
    assert r.status == 400
    missions = await (await client.get("/api/missions", headers=h)).json()
    assert missions[0]["t_start"] == 1_700_000_005.0
    assert missions[0]["t_end"] == 1_700_000_060.0


async def test_gallery_filters(gs_client: TestClient[Any, Any]) -> None:
    import time

    now = time.time()
    a, b = Encoder(7, "uav1", KEY), Encoder(7, "uav2", KEY)
    feed(gs_client, a, 1, now=now, payload=b"a" * 100, red=0.2)
    feed(gs_client, a, 2, now=now, payload=b"a" * 100, red=0.0, object=True)
    feed(gs_client, b, 1, now=now, payload=b"b" * 100, red=0.9)
    await gs_client.server.app[STORAGE].flush()

    async def gallery(**q: str) -> list[tuple[str, int]]:
        body = await (await gs_client.get("/api/images", params=q, headers=auth())).json()
        return [(im["sender"], im["seq"]) for im in body["images"]]

    assert await gallery() == [("uav1", 2), ("uav2", 1), ("uav1", 1)]
    assert await gallery(drone="uav1") == [("uav1", 2), ("uav1", 1)]
    assert await gallery(object="true") == [("uav1", 2)]
    assert await gallery(object="false", drone="uav2") == [("uav2", 1)]
    body = await (await gs_client.get("/api/images", headers=auth())).json()
    img = await gs_client.get(body["images"][0]["url"], headers=auth())
    assert img.status == 200 and await img.read() == b"a" * 100
    assert (await gs_client.get("/api/images/999.jpg", headers=auth())).status == 404
    assert (await gs_client.get("/api/images", params={"limit": "x"}, headers=auth())).status == 400
    assert len(await gallery(order="time", object="any")) == 3  # the valid values still work
    # were ignored (200, every image, best first) where limit=x was a 400
    for bad, error in ({"order": "bogus"}, "order must be utility or time, got 'bogus'"), \
            ({"object": "maybe"}, "object must be true, false or any, got 'maybe'"):
        r = await gs_client.get("/api/images", params=bad, headers=auth())
        assert r.status == 400 and await r.json() == {"error": error}


async def test_garbage_and_mutations_are_counted_never_raised(
    gs_client: TestClient[Any, Any],
) -> None:
    import random
    import time

    rng = random.Random(6)
    link = gs_client.server.app[LINK]
    enc = Encoder(7, "uav1", KEY)
    m = Message(sender="uav1", seq=1, type="image", t_gen=time.time(), size=2500, data={})
    valid = enc.fragment(m, rng.randbytes(2500), time.time())
    sent = 0
    for i in range(300):
        if i % 3 == 0:
            data = rng.randbytes(rng.randrange(0, 1400))
        else:
            data = bytearray(rng.choice(valid))
            for _ in range(rng.randrange(1, 4)):
                data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
            data = bytes(data)
        link.datagram_received(data, ADDR)
        sent += 1
    counters = link.decoder.counters
    assert counters["datagrams"] == sent
    assert counters["accepted"] == 0  # every mutation breaks the tag or the header
    rejected = sum(
        counters[k]
        for k in (
            "malformed",
            "bad_tag",
            "wrong_fleet",
            "oversize",
            "unsupported_version",
            "stale",
            "replayed",
        )
    )
    assert rejected == sent
    stats = await (await gs_client.get("/api/stats", headers=auth())).json()
    assert sum(stats["drops"].values()) == sent
    assert link.fleet.drones == {}
