"""Two drones whose ids differ only in characters a path cannot hold (2026-11-25).

``safe_name`` replaced such characters with ``_``, so ``Möwe1`` and ``Mäwe1`` (or ``uav 1``
and ``uav_1``) shared one image folder: the second drone's image 1 replaced the first's file,
and the first drone's row in the database then served the second's picture (the dashboard
showed one drone's image as the other's; the export copied one over the other). Now an id
that needs cleaning gets a hash of itself in its name: one folder, and one export file name,
per id.
"""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import pytest
from aiohttp.test_utils import TestClient

from ground_station.export import export_mission
from ground_station.fake_drone import FakeDrone, synthetic_jpeg
from ground_station.keys import LINK
from ground_station.storage import Storage, StoreItem
from ground_station.storage_records import safe_name
from tests.ground_station.conftest import KEY, auth
from utility_specs.message import Message

T0 = 1_700_000_000.0
PAIRS = [("Möwe1", "Mäwe1"), ("uav 1", "uav_1"), ("uav/1", "uav_1"), ("..", "_."),
         ("a" * 65, "a" * 64 + "b")]


@pytest.mark.parametrize(("one", "other"), PAIRS)
def test_distinct_ids_get_distinct_safe_names(one: str, other: str) -> None:
    names = {safe_name(one), safe_name(other), safe_name(one + "\x00"), safe_name("")}
    assert len(names) == 4
    for name in names:
        assert 0 < len(name) <= 64 and "/" not in name and "\x00" not in name
        assert name not in (".", "..")
    assert safe_name("drone-1.a_B") == "drone-1.a_B"  # a clean id is its own name


def _image(sender: str, payload: bytes) -> StoreItem:
    m = Message(sender=sender, seq=1, type="image", t_gen=T0, t_sent=T0, t_rcv=T0 + 0.2,
                size=len(payload), receiver="gs",
                data={"red": 0.0, "lat_deg": 47.39, "lon_deg": 8.54, "pose_age_s": 0.1})
    return StoreItem(mission="m", message=m, payload=payload, utility=1.0)


def test_the_export_keeps_both_drones_images(tmp_path: Path) -> None:
    storage = Storage(tmp_path / "data")
    storage.write_batch([_image("Möwe1", b"\x01" * 50), _image("Mäwe1", b"\x02" * 50)], now=T0)
    storage.close()
    result = export_mission(tmp_path / "data", "m", tmp_path / "out")
    files = sorted((tmp_path / "out" / "images").iterdir())
    assert result.images == 2 and len(files) == 2
    assert sorted(f.read_bytes() for f in files) == [b"\x01" * 50, b"\x02" * 50]


async def test_the_dashboard_shows_each_drone_its_own_image(
        gs_client: TestClient[Any, Any]) -> None:
    ground = gs_client.server.app[LINK].local_addr
    sent = {}
    for number, drone_id in enumerate(("Möwe1", "Mäwe1")):
        drone = FakeDrone(drone_id, fleet_id=7, key=KEY, ground=ground)
        await drone.open()
        sent[drone_id] = synthetic_jpeg(number, red=0.1 * number, label=drone_id)
        drone.send_image(sent[drone_id], data={"red": 0.1 * number})
        drone.close()
    async with asyncio.timeout(10):
        while len((body := await (await gs_client.get(
                "/api/images?limit=10", headers=auth())).json())["images"]) < 2:
            await asyncio.sleep(0.1)
    assert sorted(im["sender"] for im in body["images"]) == ["Mäwe1", "Möwe1"]
    for image in body["images"]:
        resp = await gs_client.get(image["url"], headers=auth())
        assert await resp.read() == sent[image["sender"]], image["sender"]
