"""``uav-ground-station shell``: the interactive mission manager of thesis fig. 3.7.

It talks to a running ground station over its JSON API (with the control token), so the
terminal and the dashboard drive the same mission manager. Commands: start, end, params,
report, wait, drones, reset, sleep, status, help, close, quit, with the thesis' letters
(s, e, p, r, n, rr, l, h, c, q) as aliases. Every wait ends after ``wait_timeout_s`` and
names the drones that did not answer; a command waits for its per-drone results.
"""

from __future__ import annotations

import asyncio
import contextlib
import datetime as dt
import os
import stat
import sys
import threading
import time
from collections.abc import Callable, Iterable
from typing import Any, TextIO

import aiohttp

from ground_station.mission_input import HELP, MissionError, ShellCommand, parse_shell_line

__all__ = ["ApiClient", "MissionShell", "run_shell"]

POLL_S = 0.25
WAIT_TIMEOUT_S = 30.0
"""Default bound of every wait (``--timeout``): a silent drone must not hang the shell."""


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


class WaitTimeout(MissionError):
    """A wait ran out of time; the text names who did not answer."""


def _result_line(drone: str, entry: dict[str, Any]) -> str:
    text = f"  {drone}: {entry['result']}"
    if entry.get("reason"):
        text += f" ({entry['reason']})"
    counters = entry.get("info", {}).get("counters")
    if isinstance(counters, dict):
        text += " " + " ".join(f"{k}={v}" for k, v in sorted(counters.items()))
    return text


class MissionShell:
    """Executes parsed lines; ``out`` receives what the operator reads."""

    def __init__(
        self, api: ApiClient, out: TextIO, *, wait_timeout_s: float | None = WAIT_TIMEOUT_S
    ):
        self.api = api
        self.out = out
        self.wait_timeout_s = wait_timeout_s
        self.last_command_id: int | None = None
        self.failed = False
        """An error was printed or a drone did not answer done (a script exits 1)."""
        self.results_shown: int | None = None
        """The command whose every result was printed (a bare ``wait`` does not repeat it)."""

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
            self.failed = True
            return True

    async def _run(self, c: ShellCommand) -> bool:
        if c.verb in ("quit", "close"):
            return False
        if c.verb == "help":
            self.say(HELP)
        elif c.verb in ("start", "end"):
            self.say("Starting mission" if c.verb == "start" else "Ending mission")
            result = await self.api.issue(c.verb, {"when": c.when or "now"})
            await self._report_command(result)
        elif c.verb == "params":
            self.say("Changing parameters")
            self.say(f"Parsed parameters: {[f'{k}={v}' for k, v in c.params.items()]}")
            result = await self.api.issue("params", {"params": dict(c.params), "when": c.when})
            await self._report_command(result)
        elif c.verb == "report":
            self.say("Asking every drone for its counters")
            result = await self.api.issue("report", {"when": c.when or "now"})
            await self._report_command(result)
        elif c.verb == "wait_drones":
            assert c.count is not None
            self.say(f"Waiting for {c.count} drone(s)")
            state = await self._wait(
                lambda m: len(m["drones"]) >= (c.count or 0),
                lambda m: f"heard {len(m['drones'])} of {c.count}: "
                f"{', '.join(m['drones']) or 'none'}",
            )
            self.say(f"{len(state['drones'])} drone(s): {', '.join(state['drones'])}")
        elif c.verb == "wait_reports":
            state = await self.api.mission()
            latest = self._latest(state)
            if c.count is None and c.report is None and latest:
                if latest.get("finished") and latest["command_id"] == self.results_shown:
                    self.say(f"nothing left to wait for: #{latest['command_id']} "
                             f"{latest['name']} has every result (above)")
                else:
                    await self._wait_results(None)
            else:
                await self._wait_reports(c.count, c.report or "done", state)
        elif c.verb == "reset_reports":
            await self.api.reset_reports()
            self.say("Reports reset")
        elif c.verb == "sleep":
            assert c.seconds is not None
            await asyncio.sleep(c.seconds)
        elif c.verb == "status":
            self._print_status(await self.api.mission())
        return True

    async def _wait_reports(self, count: int | None, name: str, state: dict[str, Any]) -> None:
        self.say(f"Waiting for {count} report(s) {name!r}" if count is not None
                 else f"Waiting for every drone's report {name!r}")

        def enough(m: dict[str, Any]) -> bool:
            if count is not None:
                return int(m["reports"].get(name, 0)) >= count
            drones = set(m["drones"])
            return bool(drones) and drones <= set(m["report_drones"].get(name, []))

        def missing(m: dict[str, Any]) -> str:
            silent = sorted(set(m["drones"]) - set(m["report_drones"].get(name, [])))
            got = int(m["reports"].get(name, 0))
            return (f"{got} report(s) {name!r}"
                    + (f"; not reported: {', '.join(silent)}" if silent else ""))

        state = await self._wait(enough, missing)
        self.say(f"Reports {name!r}: {state['reports'].get(name, 0)}")

    def _latest(self, state: dict[str, Any], command_id: int | None = None) -> dict[str, Any]:
        wanted = command_id if command_id is not None else self.last_command_id
        commands = state.get("commands", [])
        for command in reversed(commands):
            if wanted is None or command["command_id"] == wanted:
                return dict(command)
        return {}

    async def _wait_results(self, command_id: int | None) -> None:
        """Wait until every drone has a result of the command: done, error or no reply."""
        def finished(m: dict[str, Any]) -> bool:
            return bool(self._latest(m, command_id).get("finished"))

        def missing(m: dict[str, Any]) -> str:
            command = self._latest(m, command_id)
            waiting = sorted(d for d, e in command.get("results", {}).items()
                             if e["result"] not in ("done", "error", "no reply", "superseded"))
            return f"no result yet from: {', '.join(waiting) or 'none'}"

        state = await self._wait(finished, missing)
        command = self._latest(state, command_id)
        self._print_results(command)
        self.results_shown = command.get("command_id")

    def _print_results(self, command: dict[str, Any], *, judge: bool = True) -> None:
        summary = command.get("summary", {})
        total = summary.get("total", 0)
        parts = [f"done {summary.get('done', 0)}/{total}"]
        parts += [f"{k} {summary[k]}" for k in ("error", "no reply", "superseded")
                  if summary.get(k)]
        if judge and summary.get("done", 0) + summary.get("superseded", 0) != total:
            self.failed = True
        self.say(f"#{command['command_id']} {command['name']}: {', '.join(parts)}")
        for drone, entry in sorted(command.get("results", {}).items()):
            if entry["result"] != "done" or entry.get("info", {}).get("counters"):
                self.say(_result_line(drone, entry))

    def _print_status(self, state: dict[str, Any]) -> None:
        self.say(f"phase {state['phase']}; drones ({len(state['drones'])}): "
                 f"{', '.join(state['drones']) or 'none'}")
        for command in state.get("commands", [])[-5:]:
            self._print_results(command, judge=False)

    async def _report_command(self, result: dict[str, Any]) -> None:
        command = result["command"]
        drones = result["mission"]["drones"]
        self.last_command_id = command["command_id"]
        self.say(f"command #{command['command_id']} {command['name']} to {len(drones)} drone(s)")
        self.say(_stamp(command["t_exec"]))
        if not drones:
            return
        ahead = command["t_exec"] - time.time()
        if self.wait_timeout_s is not None and ahead > self.wait_timeout_s:
            self.say("results after it runs: type 'wait'")
            return
        await self._wait_results(command["command_id"])

    async def _wait(
        self, done: Callable[[dict[str, Any]], bool], missing: Callable[[dict[str, Any]], str]
    ) -> dict[str, Any]:
        """Poll the mission state until ``done``; on timeout say what is ``missing``."""
        state: dict[str, Any] = {}
        try:
            async with asyncio.timeout(self.wait_timeout_s):
                while True:
                    state = await self.api.mission()
                    if done(state):
                        return state
                    await asyncio.sleep(POLL_S)
        except TimeoutError:
            why = missing(state) if state else "no answer from the ground station"
            raise WaitTimeout(
                f"gave up waiting after {self.wait_timeout_s:g} s; {why}"
            ) from None

    async def run(self, lines: Iterable[str] | None = None, prompt: str = "CMD >> ") -> None:
        """Run given lines, or read the terminal until ``q``/``c``/EOF."""
        if lines is not None:
            for line in lines:
                if not await self.execute(line):
                    return
            return
        self.say(HELP)
        pipe = None if sys.stdin.isatty() else _PipeLines(sys.stdin, self.out)
        try:
            while True:
                try:
                    line = await (_read_line(prompt) if pipe is None else pipe.readline(prompt))
                except EOFError:
                    return
                if not await self.execute(line):
                    return
        finally:
            if pipe is not None:
                pipe.close()


async def _read_line(prompt: str) -> str:
    """``input(prompt)`` on a daemon thread, for a terminal (its line editing): on Ctrl-C the
    process exits even though the thread still waits for it (an executor thread there hung
    the exit). A pipe is read by the loop instead (:class:`_PipeLines`): a thread blocked
    in a pipe's read holds stdin's lock, and the interpreter's exit then died on it."""
    loop = asyncio.get_running_loop()
    future: asyncio.Future[str] = loop.create_future()

    def settle(line: str | None, error: Exception | None) -> None:
        if not future.done():  # cancelled meanwhile: nobody waits for this line
            if error is not None:
                future.set_exception(error)
            else:
                future.set_result(line or "")

    def read() -> None:
        try:
            line: str | None = input(prompt)
            error: Exception | None = None
        except Exception as exc:  # EOFError: the terminal or the pipe closed
            line, error = None, exc
        with contextlib.suppress(RuntimeError):  # the loop closed meanwhile (Ctrl-C)
            loop.call_soon_threadsafe(settle, line, error)

    threading.Thread(target=read, name="shell-input", daemon=True).start()
    return await future


class _PipeLines:
    """Lines of a stdin that is not a terminal, read without a thread: a pipe or socket
    through the event loop, a regular file (which never blocks) directly."""

    def __init__(self, stdin: TextIO, out: TextIO) -> None:
        self.stdin, self.out = stdin, out
        self.reader: asyncio.StreamReader | None = None
        self.transport: asyncio.BaseTransport | None = None
        self.direct = False

    async def readline(self, prompt: str) -> str:
        self.out.write(prompt)  # as input() does when stdin is not a terminal
        self.out.flush()
        if self.reader is None and not self.direct:
            mode = os.fstat(self.stdin.fileno()).st_mode
            self.direct = not (stat.S_ISFIFO(mode) or stat.S_ISSOCK(mode))  # a file, /dev/null
            if not self.direct:
                reader = asyncio.StreamReader()
                self.transport, _ = await asyncio.get_running_loop().connect_read_pipe(
                    lambda: asyncio.StreamReaderProtocol(reader), self.stdin)
                self.reader = reader
        if self.reader is None:
            data = self.stdin.readline()
        else:
            data = (await self.reader.readline()).decode(errors="replace")
        if not data:
            raise EOFError
        return data.rstrip("\r\n")

    def close(self) -> None:
        if self.transport is not None:
            self.transport.close()


async def run_shell(
    base_url: str,
    token: str,
    *,
    lines: Iterable[str] | None = None,
    out: TextIO = sys.stdout,
    wait_timeout_s: float | None = WAIT_TIMEOUT_S,
) -> int:
    """Run the shell; scripted (``lines``), exit 1 when a line failed or a drone did not
    answer ``done``, so ``uav-ground-station shell -c "start"`` can gate a script."""
    async with aiohttp.ClientSession() as session:
        shell = MissionShell(
            ApiClient(base_url, token, session), out, wait_timeout_s=wait_timeout_s
        )
        await shell.run(lines)
    return 1 if lines is not None and shell.failed else 0
