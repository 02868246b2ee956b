"""Mission commands from the ground station: acknowledged at once, executed at ``t_exec``.

``start`` and ``end`` move the mission window, ``set_params`` changes the decider's live
parameters (``done`` only once applied), ``request_report`` returns the app's counters. Every
result is remembered, so a command the ground station resends gets its result again.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable, Mapping
from typing import Any

from companion.dispatch import Dispatcher
from companion.mission import MissionWindow
from companion.mission_log import MissionLogWriter
from companion.protocol import LocalProtocolError, Status

__all__ = ["CommandExecutor", "replaced_by"]

log = logging.getLogger(__name__)

Clock = Callable[[], float]
SendStatus = Callable[[Status, float], int]
RESULTS_KEPT = 1000
PHASE_KEPT = 64


class CommandExecutor:
    """Schedules, runs and answers the commands addressed to ``drone_id``.

    ``on_done(now)`` is told after each command that changed something (the telemetry
    publisher sends a fresh status).
    """

    def __init__(self, *, drone_id: str, clock: Clock, send_status: SendStatus,
                 dispatcher: Dispatcher, mission: MissionWindow, mission_log: MissionLogWriter,
                 on_done: Callable[[float], None]) -> None:
        self._drone_id = drone_id
        self._clock = clock
        self._send_status = send_status
        self._dispatcher = dispatcher
        self._mission = mission
        self._log = mission_log
        self._on_done = on_done
        self._results: dict[int, Status | None] = {}
        """Command id -> its final status (None while it waits for ``t_exec``)."""
        self._tasks: set[asyncio.Task[None]] = set()
        self._timers: list[asyncio.TimerHandle] = []
        self._phase: dict[int, tuple[str, float]] = {}
        """Start and end commands received: id -> (name, t_exec), the last PHASE_KEPT."""

    def close(self) -> None:
        for handle in self._timers:
            handle.cancel()

    def schedule(self, command: Any) -> None:
        """Acknowledge at once, execute at ``t_exec`` (fleet clock); duplicates are ignored.

        A repeated command gets its final result again (``done``/``error``) once it has
        one, else another ack: the ground station resends until it sees a result, so a lost
        ``done`` datagram is recovered. The log line comes last and cannot stop the command.
        """
        if command.target is not None and command.target != self._drone_id:
            return
        if command.command_id in self._results:
            result = self._results[command.command_id]
            self._send_status(
                result or Status(state="ack", command_id=command.command_id), self._clock())
            return
        self._results[command.command_id] = None
        if command.name in ("start", "end"):
            self._phase[command.command_id] = (command.name, command.t_exec)
            if len(self._phase) > PHASE_KEPT:
                del self._phase[next(iter(self._phase))]
        self._dispatcher.counters["commands"] += 1
        self._send_status(Status(state="ack", command_id=command.command_id), self._clock())
        loop = asyncio.get_running_loop()
        delay = max(0.0, command.t_exec - self._clock())
        handle = loop.call_later(delay, self._execute, command)
        self._timers.append(handle)
        _log_safely(logging.INFO, "command %s #%d at %.3f (in %.3f s)", command.name,
                    command.command_id, command.t_exec, delay,
                    extra={"event": "command", "command": command.name})

    def _execute(self, command: Any) -> None:
        """Run a due command; ``set_params`` waits until the optimiser has applied it."""
        if command.name == "set_params" and self._dispatcher.started:
            task = asyncio.get_running_loop().create_task(self._apply_params(command))
            self._tasks.add(task)
            task.add_done_callback(self._tasks.discard)
            return
        now = self._clock()
        info: dict[str, Any] = {"name": command.name}
        later = replaced_by(self._phase, command)
        if later is not None:
            self._finish(command, info, skipped=True,
                         error=f"superseded by {later[1]} #{later[0]}, issued later to run "
                         "before it: the latest start or end decides")
            return
        try:
            if command.name == "start":
                self._mission.state = "running"
                self._dispatcher.mission_started()
            elif command.name == "end":
                self._mission.state = "ended"
            elif command.name == "set_params":  # no loop yet (tests driving the app directly)
                self._dispatcher.set_params_now(dict(command.args), now)
                info["params"] = dict(command.args)
            elif command.name == "request_report":
                info["counters"] = dict(self._dispatcher.counters)
            else:
                raise ValueError(f"unknown command {command.name!r}")
        except (ValueError, TypeError) as exc:
            self._finish(command, info, error=str(exc))
            return
        self._finish(command, info)

    async def _apply_params(self, command: Any) -> None:
        params = dict(command.args)
        info: dict[str, Any] = {"name": command.name, "params": params}
        try:
            await self._dispatcher.set_params(params)
        except Exception as exc:  # any rejection is the error
            self._finish(command, info, error=str(exc) or repr(exc))
            return
        self._finish(command, info)

    def _finish(self, command: Any, info: dict[str, Any], *, error: str | None = None,
                skipped: bool = False) -> None:
        """Send and remember the result; then the status message, mission log and log line
        (``skipped``: the error is the station's own choice, not a failure: INFO)."""
        now = self._clock()
        if error is None:
            status = Status(state="done", command_id=command.command_id, info=info)
        else:
            status = Status(state="error", command_id=command.command_id,
                            info={**info, "error": error})
        self._results[command.command_id] = status
        if len(self._results) > RESULTS_KEPT:  # bounded: forget the oldest
            del self._results[next(iter(self._results))]
        try:
            self._send_status(status, now)
        except (OSError, ValueError, LocalProtocolError) as exc:  # resent on the retry
            self._dispatcher.counters["send_errors"] += 1
            _log_safely(logging.WARNING, "command %s #%d: result not sent: %s",
                        command.name, command.command_id, exc)
        if error is not None:
            _log_safely(logging.INFO if skipped else logging.WARNING,
                        "command %s #%d %s: %s", command.name, command.command_id,
                        "skipped" if skipped else "failed", error)
            return
        self._on_done(now)
        self._log.write_state(self._drone_id, now, mission=self._mission.state,
                              command=command.name)
        _log_safely(logging.INFO, "command %s #%d done", command.name, command.command_id,
                    extra={"event": "command_done", "command": command.name})


def replaced_by(phase: Mapping[int, tuple[str, float]], command: Any) -> tuple[int, str] | None:
    """Of the start and end commands received (``phase``: id -> (name, t_exec)), one the
    station issued after ``command`` (a newer id) that runs at or before it: the station
    replaced ``command`` with it (``ground_station.missions``), so ``command`` must not run.
    Ids are compared as serial numbers: they wrap at 2**32."""
    if command.name not in ("start", "end"):
        return None
    for cid, (name, t_exec) in phase.items():
        if 0 < (cid - command.command_id) % 2**32 < 2**31 and t_exec <= command.t_exec:
            return cid, name
    return None


def _log_safely(level: int, msg: str, *args: Any, extra: Mapping[str, Any] | None = None
                ) -> None:
    """Log, but never let a logging problem (a bad ``extra`` key, a broken handler) stop
    the code path that logs: a command must run whether or not its log line can be made."""
    try:
        log.log(level, msg, *args, extra=dict(extra) if extra else None)
    except Exception:  # logging must not break the caller
        with contextlib.suppress(Exception):
            log.log(level, msg, *args)
