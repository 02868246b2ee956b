"""Dashboard tile pushes are throttled per drone: the first image shows at once, a burst
shows as one later push of its latest image, and no image is missing from the tile."""

from __future__ import annotations

import time
from typing import Any

from aiohttp.test_utils import TestClient

from companion.protocol import Encoder
from ground_station.keys import LINK
from ground_station.receiver import TILE_INTERVAL_S
from utility_specs.message import Message

KEY = b"ground-station-test-fleet-key"  # as in conftest.gs_config
TOKEN = "test-token-0123456789"  # as in conftest.gs_client
ADDR = ("127.0.0.1", 40002)


def feed_image(client: TestClient[Any, Any], encoder: Encoder, seq: int) -> None:
    now = time.time()
    m = Message(sender=encoder.sender, seq=seq, type="image", t_gen=now - 0.01, size=2000,
                data={"red": 0.2})
    for datagram in encoder.fragment(m, b"\xff\xd8" + b"x" * 1998, now):
        client.server.app[LINK].datagram_received(datagram, ADDR)


async def drone_pushes(ws: Any, seconds: float) -> list[tuple[float, str, int]]:
    """(arrival, drone, latest image seq) of every tile push within ``seconds``."""
    pushes: list[tuple[float, str, int]] = []
    end = time.monotonic() + seconds
    while (left := end - time.monotonic()) > 0:
        try:
            msg = await ws.receive_json(timeout=left)
        except TimeoutError:
            break
        if msg["kind"] == "drone":
            tile = msg["drone"]
            pushes.append((time.monotonic(), tile["drone"], tile["latest_image"]["seq"]))
    return pushes


async def test_burst_of_images_is_one_immediate_and_one_deferred_push(
    gs_client: TestClient[Any, Any],
) -> None:
    ws = await gs_client.ws_connect("/ws", headers={"Authorization": f"Bearer {TOKEN}"})
    assert (await ws.receive_json(timeout=5))["kind"] == "snapshot"
    uav1, uav2 = Encoder(7, "uav1", KEY), Encoder(7, "uav2", KEY)
    t0 = time.monotonic()
    for seq in range(1, 6):
        feed_image(gs_client, uav1, seq)
    feed_image(gs_client, uav2, 1)  # another drone is not held back by uav1's burst
    pushes = await drone_pushes(ws, TILE_INTERVAL_S + 1.0)
    assert [(d, s) for _, d, s in pushes] == [("uav1", 1), ("uav2", 1), ("uav1", 5)]
    assert pushes[0][0] - t0 < TILE_INTERVAL_S  # the first image is not delayed
    # the deferred push comes about one interval after the first one (timer slack allowed)
    gap = pushes[2][0] - pushes[0][0]
    assert TILE_INTERVAL_S * 0.8 <= gap < TILE_INTERVAL_S + 0.5
    # a quiet drone's next image shows at once again
    feed_image(gs_client, uav1, 6)
    t1 = time.monotonic()
    later = await drone_pushes(ws, 0.5 * TILE_INTERVAL_S)
    assert [(d, s) for _, d, s in later] == [("uav1", 6)] and later[0][0] - t1 < TILE_INTERVAL_S
    await ws.close()
