"""``POST /api/mission/params`` with a JSON object is held to the shell's rules (names, finite
scalar values) and to one command datagram. It took anything: ``1e400`` became Infinity in
the mission state every dashboard parses (JSON.parse fails on it), nested values and a
100 kB name were stored and broadcast, and a command too big for a datagram was accepted,
never sent, and raised a "command not sent" alert at every retry."""

from __future__ import annotations

import json
from typing import Any

import pytest
from aiohttp.test_utils import TestClient

TOKEN = "test-token-0123456789"  # as in tests/ground_station/conftest.py
AUTH = {"Authorization": f"Bearer {TOKEN}", "Content-Type": "application/json"}


@pytest.mark.parametrize(("body", "error"), [
    (b'{"params": {"alpha": 1e400}}', "parameter alpha: expected a finite number"),
    (b'{"params": {"alpha": NaN}}', "parameter alpha: expected a finite number"),
    (b'{"params": {"alpha": -Infinity}}', "parameter alpha: expected a finite number"),
    (b'{"params": {"alpha": [1]}}', "parameter alpha: expected a number, true/false or text"),
    (b'{"params": {"alpha": {"x": 1}}}',
     "parameter alpha: expected a number, true/false or text"),
    (b'{"params": {"alpha": null}}', "parameter alpha: expected a number, true/false or text"),
    (b'{"params": {"": 1}}', "parameter name '': expected up to 64 letters"),
    (b'{"params": {"a b": 1}}', "parameter name 'a b': expected up to 64 letters"),
    (b'{"params": {"' + b"a" * 100_000 + b'": 1}}', "expected up to 64 letters"),
    (json.dumps({"params": {f"p{i}": "v" * 60 for i in range(30)}}).encode(),
     "params: command of "),
])
async def test_params_objects_are_checked(gs_client: TestClient[Any, Any], body: bytes,
                                          error: str) -> None:
    resp = await gs_client.post("/api/mission/params", data=body, headers=AUTH)
    assert resp.status == 400
    assert error in (await resp.json())["error"]
    mission = await (await gs_client.get("/api/mission", headers=AUTH)).json()
    assert mission["params"] == {} and mission["commands"] == []


async def test_a_start_with_bad_args_is_refused(gs_client: TestClient[Any, Any]) -> None:
    resp = await gs_client.post("/api/mission/start", json={"args": {"x": 1e400}},
                                headers=AUTH)
    assert resp.status == 400
    mission = await (await gs_client.get("/api/mission", headers=AUTH)).json()
    assert mission["phase"] == "idle" and mission["commands"] == []


async def test_good_params_objects_still_go_out(gs_client: TestClient[Any, Any]) -> None:
    params = {"alpha": 10, "mcts_iterations": 300, "fast": True, "policy": "mcts",
              "weights.image": 0.5}
    resp = await gs_client.post("/api/mission/params", json={"params": params}, headers=AUTH)
    assert resp.status == 200
    mission = await (await gs_client.get("/api/mission", headers=AUTH)).json()
    assert mission["params"] == params and len(mission["commands"]) == 1
