"""Per-drone command results over real UDP: done, error with its reason, no reply.

The API, the WebSocket (what the dashboard draws) and the shell show the same results; every
shell wait ends and names who did not answer (issue 11, symptoms 4 and 6).
"""

from __future__ import annotations

import asyncio
import io
import time
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import aiohttp
import pytest
from aiohttp.test_utils import TestClient

from ground_station.app import create_app
from ground_station.config import GroundConfig
from ground_station.fake_drone import FakeDrone
from ground_station.keys import LINK
from ground_station.shell import ApiClient, MissionShell, run_shell
from tests.keys import TEST_COMMAND_KEY, TEST_COMMAND_PUB

KEY = b"integration-test-fleet-key-0002"
TOKEN = "integration-token-commands"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


@pytest.fixture
async def station(
    tmp_path: Path, aiohttp_client: Callable[..., Any]
) -> AsyncIterator[TestClient[Any, Any]]:
    config = GroundConfig(fleet_id=5, fleet_key=KEY, command_key=TEST_COMMAND_KEY,
                          data_dir=tmp_path / "gs", mission="c",
                          udp_host="127.0.0.1", udp_port=0, report_interval_s=0.1,
                          command_retry_s=0.1, command_reply_timeout_s=0.6, fsync=False)
    client: TestClient[Any, Any] = await aiohttp_client(create_app(config, token=TOKEN))
    yield client


async def until(predicate: Callable[[], bool], timeout: float = 5.0) -> None:
    async with asyncio.timeout(timeout):
        while not predicate():
            await asyncio.sleep(0.01)


async def fleet(station: TestClient[Any, Any]) -> list[FakeDrone]:
    """ok answers done; picky answers error; silent only acknowledges."""
    app = station.server.app
    drones = []
    for name in ("ok", "picky", "silent"):
        drone = FakeDrone(name, fleet_id=5, key=KEY, ground=app[LINK].local_addr,
                          auto_done=name == "ok", command_public_key=TEST_COMMAND_PUB)
        await drone.open()
        drone.send_telemetry("status", {"mode": "GUIDED"})
        drones.append(drone)
    await until(lambda: len(app[LINK].fleet.drones) == 3)
    return drones


def reject_when_commanded(drone: FakeDrone, reason: str) -> None:
    def on_command() -> None:
        for event in drone.commands:
            drone.send_status("error", command_id=event.command.command_id,
                              info={"name": event.command.name, "error": reason})
    original = drone.datagram_received

    def receive(data: bytes, addr: Any) -> None:
        n = len(drone.commands)
        original(data, addr)
        if len(drone.commands) > n:
            on_command()
    drone.datagram_received = receive  # type: ignore[method-assign]


async def shell_output(station: TestClient[Any, Any], lines: list[str], timeout_s: float) -> str:
    out = io.StringIO()
    api = ApiClient(str(station.make_url("")), TOKEN, station.session)
    await MissionShell(api, out, wait_timeout_s=timeout_s).run(lines)
    return out.getvalue()


async def test_results_per_drone_in_the_api_and_the_shell(
        station: TestClient[Any, Any]) -> None:
    drones = await fleet(station)
    reject_when_commanded(drones[1], "alpha: no information type of the mission uses alpha")
    t0 = time.monotonic()
    text = await shell_output(station, ["params alpha=3"], timeout_s=10.0)
    assert time.monotonic() - t0 < 5.0  # ends at the reply timeout, not the wait timeout
    assert "#" in text and "set_params: done 1/3, error 1, no reply 1" in text
    assert "  picky: error (alpha: no information type of the mission uses alpha)" in text
    assert "  silent: no reply (no result 0.6 s after execution)" in text
    mission = await (await station.get("/api/mission", headers=AUTH)).json()
    [command] = mission["commands"]
    assert {d: e["result"] for d, e in command["results"].items()} == {
        "ok": "done", "picky": "error", "silent": "no reply"}
    assert command["results"]["picky"]["reason"] == \
        "alpha: no information type of the mission uses alpha"
    assert command["summary"] == {"done": 1, "error": 1, "no reply": 1, "waiting": 0,
                                  "total": 3}
    assert command["finished"] is True
    # a late "done" of the silent drone still counts
    drones[2].send_status("done", command_id=command["command_id"])
    await until(lambda: station.server.app[LINK].missions.commands[
        command["command_id"]].results.get("silent") is not None)
    text = await shell_output(station, ["wait"], timeout_s=1.0)
    assert "done 2/3, error 1" in text  # r / wait without a name: the last command
    # scripted (-c), a failed command is a failed script; all done is success
    out = io.StringIO()
    code = await run_shell(str(station.make_url("")), TOKEN, lines=["params alpha=3"], out=out,
                           wait_timeout_s=5.0)
    assert code == 1 and "error 1" in out.getvalue()
    drones[1].datagram_received = FakeDrone.datagram_received.__get__(drones[1])  # type: ignore[method-assign]
    drones[1].auto_done = drones[2].auto_done = True
    code = await run_shell(str(station.make_url("")), TOKEN, lines=["end", "status"], out=out,
                           wait_timeout_s=5.0)
    assert code == 0, out.getvalue()
    for drone in drones:
        drone.close()


async def test_the_fake_drone_refuses_what_the_companion_refuses(
        station: TestClient[Any, Any]) -> None:
    """The fake answers set_params as the companion's own decider on its defaults does: a
    bad value or an unknown name is an error with the companion's reason, not 'done'."""
    ok = (await fleet(station))[0]
    text = await shell_output(station, ["params alpha=abc"], timeout_s=10.0)
    assert "  ok: error (alpha must be a number >= 0, got 'abc')" in text, text
    text = await shell_output(station, ["params mcts_iterations=0"], timeout_s=10.0)
    assert "  ok: error (mcts_iterations must be a whole number >= 1, got 0)" in text, text
    text = await shell_output(station, ["params bogus=1"], timeout_s=10.0)
    assert "  ok: error (unknown parameter 'bogus'" in text, text
    text = await shell_output(station, ["params alpha=3, mcts_iterations=40"], timeout_s=10.0)
    assert "set_params: done 1/3" in text and "  ok: error" not in text, text
    assert len(ok.done) == 1 and len(ok.errors) == 3
    print(text)


async def test_every_wait_ends_and_names_who_did_not_answer(
        station: TestClient[Any, Any]) -> None:
    drones = await fleet(station)
    text = await shell_output(station, ["n 5", "r 3 landed", "drones 3", "q"], timeout_s=0.5)
    assert "error: gave up waiting after 0.5 s; heard 3 of 5: ok, picky, silent" in text
    assert ("error: gave up waiting after 0.5 s; 0 report(s) 'landed'; "
            "not reported: ok, picky, silent") in text
    assert "3 drone(s): ok, picky, silent" in text
    text = await shell_output(station, ["help"], timeout_s=0.5)
    for name in ("start", "end", "params", "report", "wait", "drones", "sleep", "help", "quit"):
        assert f"\n  {name} " in text
    for drone in drones:
        drone.close()


async def test_the_dashboard_sees_the_phase_and_results_change_with_time(
        station: TestClient[Any, Any]) -> None:
    """Symptom 6: after the start time the badge must say running, with no new command."""
    drones = await fleet(station)
    resp = await station.post("/api/mission/start", json={"delay_s": 0.5}, headers=AUTH)
    t_start = (await resp.json())["command"]["t_exec"]
    phases: list[tuple[float, str]] = []
    results: dict[str, str] = {}
    async with station.session.ws_connect(station.make_url("/ws"), headers=AUTH) as ws:
        async with asyncio.timeout(8.0):
            while not (phases and phases[-1][1] == "running" and results.get("silent")
                       == "no reply"):
                msg = await ws.receive()
                assert msg.type == aiohttp.WSMsgType.TEXT
                event = msg.json()
                mission = event.get("mission")
                if mission and event["kind"] in ("tick", "mission", "snapshot"):
                    phases.append((time.time(), mission["phase"]))
                    command = mission["commands"][-1]
                    results = {d: e["result"] for d, e in command["results"].items()}
    assert phases[-1][0] >= t_start
    assert results == {"ok": "done", "picky": "no reply", "silent": "no reply"}
    for drone in drones:
        drone.close()
