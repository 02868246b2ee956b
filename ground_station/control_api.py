"""The control API: mission start/end, live parameters and report requests, each issued to
every drone through the mission manager, stored, announced as an alert and broadcast.
"""

from __future__ import annotations

import json
from typing import Any

from aiohttp import web

from companion.protocol import Command, LocalProtocolError
from ground_station.fleet import Alert
from ground_station.http_guard import json_reply
from ground_station.keys import (
    BROADCASTER,
    CLOCK,
    CONFIG,
    FLEET,
    LINK,
    MISSIONS,
    STORAGE,
)
from ground_station.mission_input import MissionError, check_params, parse_params, parse_when
from ground_station.missions import COMMAND_NAMES

__all__ = ["MAX_T_EXEC_OFFSET_S", "api_end", "api_params", "api_report", "api_reset_reports",
           "api_start"]

MAX_T_EXEC_OFFSET_S = 7 * 86400.0
"""How far from the station's clock a command's execution time may be. Beyond it a time is
a mistake or an attack, not a plan: 1e18 overflowed ``time.localtime`` after the command was
issued (a 500, a traceback, the command neither saved nor broadcast), and a start in 1970
became the mission's ``t_start``, which the report drew in 5 s bins from 1970 on."""


async def _body(request: web.Request) -> dict[str, Any]:
    if not request.can_read_body:
        return {}
    try:
        body = await request.json()
    except (ValueError, RecursionError):  # bad JSON or text; nesting deeper than Python's stack
        raise web.HTTPBadRequest(
            text=json.dumps({"error": "body must be a JSON object"}),
            content_type="application/json",
        ) from None
    if not isinstance(body, dict):
        raise web.HTTPBadRequest(
            text=json.dumps({"error": "body must be a JSON object"}),
            content_type="application/json",
        )
    return body


def _t_exec(body: dict[str, Any], now: float) -> float:
    t_exec = _requested_t_exec(body, now)
    if not abs(t_exec - now) <= MAX_T_EXEC_OFFSET_S:
        raise MissionError(f"t_exec: expected a time within {MAX_T_EXEC_OFFSET_S / 86400:g} "
                           "days of the station's clock (fleet clock, Unix seconds)")
    return t_exec


def _requested_t_exec(body: dict[str, Any], now: float) -> float:
    if "t_exec" in body:
        value = body["t_exec"]
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise MissionError("t_exec: expected a number (fleet clock, Unix seconds)")
        return float(value)
    if "delay_s" in body:
        value = body["delay_s"]
        if isinstance(value, bool) or not isinstance(value, int | float) or value < 0:
            raise MissionError("delay_s: expected a number of seconds >= 0")
        return now + float(value)
    when = body.get("when")
    if when is not None and not isinstance(when, str):
        raise MissionError("when: expected text like 'in 5 s' or 'at 14:00'")
    return parse_when(when, now=now)


def _fits_one_datagram(app: web.Application, verb: str, t_exec: float,
                      args: dict[str, Any]) -> None:
    """A command too big for one datagram is refused now: accepted, it was never sent, and
    every retry raised a "command not sent" alert."""
    try:
        command = Command(command_id=1, name=COMMAND_NAMES[verb], t_exec=t_exec, args=args)
        app[LINK].encoder.encode_command(command, 0.0)
    except (LocalProtocolError, ValueError) as exc:  # ValueError: t_exec of 1e999
        raise MissionError(f"{verb}: {exc}") from None


def _when(t_exec: float, now: float) -> str:
    """When a command runs, relative to its alert's own time: a clock time in the station's
    zone and 24-hour format sat next to the dashboard's browser-formatted times (21:58:33
    beside 9:58:32 PM)."""
    ahead = t_exec - now
    if abs(ahead) < 0.5:
        return "now"
    return f"in {ahead:.0f} s" if ahead > 0 else f"{-ahead:.0f} s ago"


async def _issue(request: web.Request, verb: str) -> web.Response:
    app = request.app
    now = app[CLOCK]()
    body = await _body(request)
    try:
        t_exec = _t_exec(body, now)
        args: dict[str, Any] = {}
        if verb == "params":
            raw = body.get("params")
            if isinstance(raw, str):
                args = parse_params(raw)
            elif isinstance(raw, dict) and raw:
                args = check_params(raw)
            else:
                raise MissionError("params: expected an object or 'NAME=VALUE,...' text")
        elif isinstance(body.get("args"), dict):
            args = check_params(body["args"]) if body["args"] else {}
        _fits_one_datagram(app, verb, t_exec, args)
        issued = app[MISSIONS].issue(verb, t_exec=t_exec, now=now, args=args)
    except MissionError as exc:
        return json_reply({"error": str(exc)}, status=400)
    mission = app[CONFIG].mission
    fleet = app[FLEET]
    try:  # the command is issued either way; a storage failure is shown, not a 500
        cancelled = [c.command.t_exec for c in app[MISSIONS].commands.values()
                     if c.superseded_by == issued.command.command_id and c.command.name == "start"]
        if cancelled:
            await app[STORAGE].call_writer(lambda s: s.cancel_starts(mission, cancelled, now=now))
        if verb == "start":
            await app[STORAGE].call_writer(
                lambda s: s.mark_mission(mission, now=now, t_start=t_exec))
        elif verb == "end" and app[MISSIONS].t_end == t_exec:
            await app[STORAGE].call_writer(lambda s: s.mark_mission(mission, now=now, t_end=t_exec))
    except Exception as exc:  # full disk, SQLite errors...
        fleet.alert(Alert(t=now, level="error", kind="storage",
                          text=f"mission {verb} not stored: {exc}"))
    fleet.alert(
        Alert(
            t=now,
            level="info",
            kind="mission",
            text=f"{issued.command.name} {_when(t_exec, now)}: sent to "
            f"{len(app[MISSIONS].drones)} drone(s)",
        )
    )
    link = app[LINK]
    link.kick()
    link._flush_alerts()
    await link.save_mission_state()  # acknowledged: a restart must not lose it
    state = app[MISSIONS].state(now=now)
    app[BROADCASTER].publish("mission", {"mission": state})
    return json_reply({"command": issued.as_json(now), "mission": state})


async def api_start(request: web.Request) -> web.Response:
    return await _issue(request, "start")


async def api_end(request: web.Request) -> web.Response:
    return await _issue(request, "end")


async def api_params(request: web.Request) -> web.Response:
    return await _issue(request, "params")


async def api_report(request: web.Request) -> web.Response:
    return await _issue(request, "report")


async def api_reset_reports(request: web.Request) -> web.Response:
    app = request.app
    app[MISSIONS].reset_reports()
    return json_reply(app[MISSIONS].state(now=app[CLOCK]()))
