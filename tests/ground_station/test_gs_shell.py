"""The interactive terminal (thesis fig. 3.7) driving the app's JSON API."""

from __future__ import annotations

import asyncio
import io
import time
from typing import Any

from aiohttp.test_utils import TestClient

from ground_station.keys import MISSIONS
from ground_station.shell import ApiClient, MissionShell

TOKEN_VALUE = "test-token-0123456789"  # as in conftest.gs_client


async def run_lines(client: TestClient[Any, Any], lines: list[str]) -> str:
    out = io.StringIO()
    api = ApiClient(str(client.make_url("")), TOKEN_VALUE, client.session)
    await MissionShell(api, out, wait_timeout_s=2.0).run(lines)
    return out.getvalue()


async def test_figure_3_7_session(gs_client: TestClient[Any, Any]) -> None:
    text = await run_lines(
        gs_client,
        ["s +5", "p J=1,K=1,M=4", "e +5", "h", "n 0", "r 0 done", "rr", "l 0", "q", "s"],
    )
    lines = text.splitlines()
    assert lines[0] == "Starting mission"
    assert lines[1].startswith("command #") and lines[1].endswith("start to 0 drone(s)")
    assert lines[2].startswith("@20")
    assert "Changing parameters" in lines
    assert "Parsed parameters: ['J=1', 'K=1', 'M=4']" in lines
    assert "Ending mission" in lines and "Available commands:" in lines
    assert "Reports 'done': 0" in lines and "Reports reset" in lines
    mm = gs_client.server.app[MISSIONS]
    assert [c.command.name for c in mm.commands.values()] == ["start", "set_params", "end"]
    assert mm.params == {"J": 1, "K": 1, "M": 4}
    assert text.count("Starting mission") == 1  # nothing runs after q


async def test_errors_are_printed_not_raised(gs_client: TestClient[Any, Any]) -> None:
    text = await run_lines(gs_client, ["x", "s whenever", "p nothing", "n 3"])
    assert "error: unknown command 'x'" in text
    assert "error: /api/mission/start: time 'whenever'" in text
    assert "error: parameter 'nothing': expected NAME=VALUE" in text
    assert "error: gave up waiting" in text  # n 3 with no drones, 2 s timeout


async def test_wait_for_every_drone_done(gs_client: TestClient[Any, Any]) -> None:
    mm = gs_client.server.app[MISSIONS]
    mm.on_status("d1", state="done", command_id=None, now=0.0)
    mm.on_status("d2", state="running", command_id=None, now=0.0)
    text = await run_lines(gs_client, ["n 2", "r 1 done"])
    assert "2 drone(s): d1, d2" in text and "Reports 'done': 1" in text
    mm.on_status("d2", state="done", command_id=None, now=1.0)
    text = await run_lines(gs_client, ["r"])
    assert "Reports 'done': 2" in text


async def test_a_wait_after_a_command_that_waited_does_not_print_its_results_again(
        gs_client: TestClient[Any, Any]) -> None:
    """``start; wait`` printed ``#1 start: done 1/1`` twice: start had already waited."""
    mm = gs_client.server.app[MISSIONS]
    mm.on_drone_heard("d1", now=time.time())

    async def answer() -> None:  # the drone says done to every command
        while True:
            for cid in list(mm.commands):
                mm.on_status("d1", state="done", command_id=cid, now=time.time())
            await asyncio.sleep(0.05)

    drone = asyncio.create_task(answer())
    try:
        text = await run_lines(gs_client, ["start", "wait", "end", "wait"])
    finally:
        drone.cancel()
    assert text.count("start: done 1/1") == 1, text
    assert text.count("end: done 1/1") == 1, text
    first, second = sorted(mm.commands)
    assert f"nothing left to wait for: #{first} start has every result (above)" in text
    assert f"nothing left to wait for: #{second} end has every result (above)" in text


async def test_a_wait_for_reports_says_how_many_of_which(
        gs_client: TestClient[Any, Any]) -> None:
    """``wait 2 foo`` said "Waiting for 2's report 'foo'". A report no drone has given yet
    is still waited for (a drone's ``"report": "landed"`` comes when it lands)."""
    mm = gs_client.server.app[MISSIONS]
    mm.on_report("d1", "foo", now=time.time())
    text = await run_lines(gs_client, ["wait 1 foo", "wait 0 done"])
    assert text.splitlines() == ["Waiting for 1 report(s) 'foo'", "Reports 'foo': 1",
                                 "Waiting for 0 report(s) 'done'", "Reports 'done': 0"]
