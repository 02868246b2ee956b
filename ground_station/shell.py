"""``uav-ground-station shell``: the interactive mission manager of thesis fig. 3.7.

It talks to a running ground station over its JSON API (with the control token), so the
terminal and the dashboard drive the same mission manager. Commands: s, e, p, n, r, rr,
l, h, c, q (``h`` prints them).
"""

from __future__ import annotations

import asyncio
import datetime as dt
import sys
from collections.abc import Callable, Iterable
from typing import Any, TextIO

import aiohttp

from ground_station.missions import HELP, MissionError, ShellCommand, parse_shell_line

__all__ = ["ApiClient", "MissionShell", "run_shell"]

POLL_S = 0.25


class ApiClient:
    """The few API calls the shell needs; errors become :class:`MissionError` text."""

    def __init__(self, base_url: str, token: str, session: aiohttp.ClientSession) -> None:
        self.base_url = base_url.rstrip("/")
        self.session = session
        self.headers = {"Authorization": f"Bearer {token}"}

    async def _call(self, method: str, path: str, body: Any = None) -> dict[str, Any]:
        try:
            async with self.session.request(
                method, self.base_url + path, json=body, headers=self.headers
            ) as resp:
                data = await resp.json(content_type=None)
                if resp.status != 200:
                    raise MissionError(f"{path}: {data.get('error', resp.reason)}")
                return dict(data)
        except aiohttp.ClientError as exc:
            raise MissionError(f"ground station at {self.base_url} unreachable: {exc}") from exc

    async def mission(self) -> dict[str, Any]:
        return await self._call("GET", "/api/mission")

    async def issue(self, verb: str, body: dict[str, Any]) -> dict[str, Any]:
        return await self._call("POST", f"/api/mission/{verb}", body)

    async def reset_reports(self) -> dict[str, Any]:
        return await self._call("POST", "/api/mission/reports/reset", {})


def _stamp(t: float) -> str:
    return "@" + dt.datetime.fromtimestamp(t).isoformat(sep=" ")


class MissionShell:
    """Executes parsed lines; ``out`` receives what the operator reads."""

    def __init__(self, api: ApiClient, out: TextIO, *, wait_timeout_s: float | None = None):
        self.api = api
        self.out = out
        self.wait_timeout_s = wait_timeout_s

    def say(self, text: str) -> None:
        self.out.write(text + "\n")
        self.out.flush()

    async def execute(self, line: str) -> bool:
        """Run one line; returns False when the shell should stop."""
        try:
            command = parse_shell_line(line)
            if command is None:
                return True
            return await self._run(command)
        except MissionError as exc:
            self.say(f"error: {exc}")
            return True
        except TimeoutError:
            self.say("error: gave up waiting")
            return True

    async def _run(self, c: ShellCommand) -> bool:
        if c.verb in ("quit", "close"):
            return False
        if c.verb == "help":
            self.say(HELP)
        elif c.verb in ("start", "end"):
            self.say("Starting mission" if c.verb == "start" else "Ending mission")
            result = await self.api.issue(c.verb, {"when": c.when or "now"})
            self._report_command(result)
        elif c.verb == "params":
            self.say("Changing parameters")
            self.say(f"Parsed parameters: {[f'{k}={v}' for k, v in c.params.items()]}")
            result = await self.api.issue("params", {"params": dict(c.params), "when": c.when})
            self._report_command(result)
        elif c.verb == "wait_drones":
            assert c.count is not None
            self.say(f"Waiting for {c.count} drone(s)")
            state = await self._wait(lambda m: len(m["drones"]) >= (c.count or 0))
            self.say(f"{len(state['drones'])} drone(s): {', '.join(state['drones'])}")
        elif c.verb == "wait_reports":
            name = c.report or "done"
            self.say(
                f"Waiting for {c.count if c.count is not None else 'every drone'}'s report {name!r}"
            )

            def enough(m: dict[str, Any]) -> bool:
                if c.count is not None:
                    return int(m["reports"].get(name, 0)) >= c.count
                drones = set(m["drones"])
                return bool(drones) and drones <= set(m["report_drones"].get(name, []))

            state = await self._wait(enough)
            self.say(f"Reports {name!r}: {state['reports'].get(name, 0)}")
        elif c.verb == "reset_reports":
            await self.api.reset_reports()
            self.say("Reports reset")
        elif c.verb == "sleep":
            assert c.seconds is not None
            await asyncio.sleep(c.seconds)
        return True

    def _report_command(self, result: dict[str, Any]) -> None:
        command = result["command"]
        drones = result["mission"]["drones"]
        self.say(f"command #{command['command_id']} {command['name']} to {len(drones)} drone(s)")
        self.say(_stamp(command["t_exec"]))

    async def _wait(self, done: Callable[[dict[str, Any]], bool]) -> dict[str, Any]:
        async with asyncio.timeout(self.wait_timeout_s):
            while True:
                state = await self.api.mission()
                if done(state):
                    return state
                await asyncio.sleep(POLL_S)

    async def run(self, lines: Iterable[str] | None = None, prompt: str = "CMD >> ") -> None:
        """Run given lines, or read the terminal until ``q``/``c``/EOF."""
        if lines is not None:
            for line in lines:
                if not await self.execute(line):
                    return
            return
        self.say(HELP)
        while True:
            try:
                line = await asyncio.to_thread(input, prompt)
            except EOFError:
                return
            if not await self.execute(line):
                return


async def run_shell(
    base_url: str,
    token: str,
    *,
    lines: Iterable[str] | None = None,
    out: TextIO = sys.stdout,
    wait_timeout_s: float | None = None,
) -> int:
    async with aiohttp.ClientSession() as session:
        shell = MissionShell(
            ApiClient(base_url, token, session), out, wait_timeout_s=wait_timeout_s
        )
        await shell.run(lines)
    return 0
