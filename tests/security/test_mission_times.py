"""Execution times a control request may ask for (docs/security.md, findings of 2026-11-24).

A finite but absurd ``t_exec`` (1e18, -1e300, or ``delay_s`` 1e17) used to be issued to the
fleet and then overflow ``time.localtime`` while the alert text was built: a 500 with a
traceback in the log, the command in memory but neither saved nor broadcast. A start in 1970
was accepted and became the mission's ``t_start``.
"""

from __future__ import annotations

import time
from typing import Any

import pytest
from aiohttp.test_utils import TestClient

from ground_station.control_api import MAX_T_EXEC_OFFSET_S
from ground_station.keys import MISSIONS
from tests.ground_station.conftest import auth


@pytest.mark.parametrize("body", [{"t_exec": 1e18}, {"t_exec": -1e300}, {"t_exec": 1e300},
                                  {"t_exec": -5}, {"t_exec": 0}, {"delay_s": 1e17},
                                  {"delay_s": MAX_T_EXEC_OFFSET_S + 60}])
@pytest.mark.parametrize("route", ["start", "end", "params", "report"])
async def test_a_time_far_from_now_is_refused_before_anything_is_issued(
        gs_client: TestClient[Any, Any], body: dict[str, Any], route: str) -> None:
    payload = body | ({"params": {"alpha": 2}} if route == "params" else {})
    resp = await gs_client.post(f"/api/mission/{route}", json=payload, headers=auth())
    assert resp.status == 400, (body, resp.status, await resp.text())
    assert (await resp.json())["error"].startswith("t_exec: expected a time within 7 days")
    assert gs_client.app[MISSIONS].commands == {}


async def test_times_within_the_window_are_issued(gs_client: TestClient[Any, Any]) -> None:
    now = time.time()
    for t_exec in (now - 3600, now + 5, now + MAX_T_EXEC_OFFSET_S - 60):
        resp = await gs_client.post("/api/mission/start", json={"t_exec": t_exec},
                                    headers=auth())
        assert resp.status == 200, await resp.text()
        assert (await resp.json())["command"]["t_exec"] == t_exec
