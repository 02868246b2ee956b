"""Fixtures shared by the ground-station tests: a config in tmp_path and a live app client."""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import pytest
from aiohttp.test_utils import TestClient

from ground_station.app import create_app
from ground_station.config import GroundConfig
from tests.keys import TEST_COMMAND_KEY

KEY = b"ground-station-test-fleet-key"
TOKEN = "test-token-0123456789"


@pytest.fixture
def gs_config(tmp_path: Path) -> GroundConfig:
    return GroundConfig(
        fleet_id=7,
        fleet_key=KEY,
        command_key=TEST_COMMAND_KEY,
        data_dir=tmp_path / "gs",
        mission="m1",
        udp_host="127.0.0.1",
        udp_port=0,
        report_interval_s=0.05,
        command_retry_s=0.1,
        fsync=False,
    )


@pytest.fixture
async def gs_client(
    gs_config: GroundConfig, aiohttp_client: Callable[..., Any]
) -> AsyncIterator[TestClient[Any, Any]]:
    client: TestClient[Any, Any] = await aiohttp_client(create_app(gs_config, token=TOKEN))
    yield client


def auth() -> dict[str, str]:
    return {"Authorization": f"Bearer {TOKEN}"}
