"""Mission manager (thesis sec. 3.3, fig. 3.7): timed fleet commands, acks, reports.

Sans-I/O: time comes in as ``now`` (fleet clock, Unix seconds). A command with a time
argument ("in 5 s", "+5", "at 14:00") becomes an absolute ``t_exec``; the shell sends it to
every known drone and sends it again every ``retry_s`` until that drone acknowledges it
(a STATUS packet naming the command id). Drones that appear while a command is still live
get it too. Each drone's result of a command is ``done``, ``error`` (with the drone's
reason) or ``no reply`` once ``reply_timeout_s`` passed after its execution time; a drone
that acknowledged but whose result did not arrive gets the command again (it answers a
repeat with its result), so a lost ``done`` datagram is recovered. Status reports
("done"...) are counted so an operator can wait for them.

A drone that lost what it was told (it restarted: a new boot epoch, or its mission state
contradicts the station's phase) gets the commands that make the mission's state again
(:meth:`MissionManager.rejoin`): the latest start, the ends after it and every set_params.
A drone heard again after a link loss gets those of them it has no result for
(:meth:`MissionManager.catch_up`), however long ago they expired.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Mapping
from typing import Any

from companion.protocol.records import Command
from ground_station.issued import FINAL, NO_REPLY, IssuedCommand
from ground_station.mission_input import (
    MissionError,
    ShellCommand,
    parse_params,
    parse_shell_line,
    parse_when,
)
from ground_station.mission_params import fleet_params

__all__ = [
    "FINAL",
    "NO_REPLY",
    "IssuedCommand",
    "MissionError",
    "MissionManager",
    "ShellCommand",
    "parse_params",
    "parse_shell_line",
    "parse_when",
]

COMMAND_NAMES = {"start": "start", "end": "end", "params": "set_params",
                 "report": "request_report"}
"""Operator verbs to the command names on the wire (companion.protocol.records.Command)."""


PARAMS_KEPT = 64
"""set_params commands kept for drones that rejoin (the oldest are forgotten first)."""
STATUS_AFTER_RESULT_S = 1.0
"""A drone's mission state generated this soon after its result may predate it (clocks)."""
CONTRADICTED_RETRY_S = 30.0
"""A drone whose mission state contradicts the station's is sent the mission's commands
again at most this often: one that did not restart answers them from its memory, and every
2 s (its statuses) they changed nothing but added a log line (39 in 38 s)."""


class MissionManager:
    """Fleet commands with absolute execution times, retransmitted until acknowledged.

    Parameters
    ----------
    retry_s
        Time between two sends of an unacknowledged command to the same drone.
    command_ttl_s
        How long after ``t_exec`` a command is still sent (to late or newly heard drones).
    reply_timeout_s
        How long after ``t_exec`` (or after the first send, for a late drone) a drone without
        a ``done``/``error`` counts as ``no reply``.
    first_command_id
        Seed of the command ids; pick it from the clock so ids differ across restarts.
    """

    def __init__(
        self,
        *,
        retry_s: float,
        command_ttl_s: float = 30.0,
        reply_timeout_s: float = 5.0,
        first_command_id: int = 1,
    ) -> None:
        if not retry_s > 0:
            raise ValueError(f"retry_s must be > 0, got {retry_s}")
        if not reply_timeout_s > 0:
            raise ValueError(f"reply_timeout_s must be > 0, got {reply_timeout_s}")
        self.retry_s = retry_s
        self.command_ttl_s = command_ttl_s
        self.reply_timeout_s = reply_timeout_s
        self._next_id = max(1, first_command_id % (2**32 - 1))
        self.drones: dict[str, float] = {}
        """Known drones -> when first heard."""
        self.heard_before: set[str] = set()
        """Drones of this mission an earlier run of the station heard (its mission state):
        not new when heard again, and not sent commands until heard."""
        self.commands: dict[int, IssuedCommand] = {}
        self.report_counts: Counter[str] = Counter()
        self.report_drones: dict[str, set[str]] = {}
        self.last_state: dict[str, str] = {}
        """Latest unsolicited status per drone."""
        self.t_start: float | None = None
        self.t_end: float | None = None
        self.params: dict[str, Any] = {}
        self.changes = 0
        """Counts changes worth saving (commands, acks, results, reports)."""
        self._contradicted: dict[str, float] = {}
        """Drone -> when its contradicting mission state last brought it back."""

    # -- inputs -------------------------------------------------------------------------
    def on_drone_heard(self, drone: str, *, now: float) -> bool:
        """Register a drone; returns True when it is new to the mission."""
        if drone in self.drones:
            return False
        self.drones[drone] = now
        self.changes += 1
        known = drone in self.heard_before
        self.heard_before.discard(drone)
        return not known

    def forget(self, drone: str) -> None:
        """Drop a drone the fleet view forgot (silent for long): no more commands to it;
        heard again, it is a new drone."""
        self.drones.pop(drone, None)
        self.heard_before.discard(drone)
        self.last_state.pop(drone, None)

    def issue(
        self, verb: str, *, t_exec: float, now: float, args: Mapping[str, Any] | None = None
    ) -> IssuedCommand:
        """Create a command for every drone (``verb``: start, end or params)."""
        if verb not in COMMAND_NAMES:
            raise MissionError(
                f"unknown mission command {verb!r}; expected {sorted(COMMAND_NAMES)}"
            )
        if not math.isfinite(t_exec):
            raise MissionError("t_exec must be a finite time")
        if verb == "params" and not args:
            raise MissionError("params: expected at least one NAME=VALUE parameter")
        command = Command(
            command_id=self._take_id(), name=COMMAND_NAMES[verb], t_exec=t_exec, args=args or {}
        )
        issued = IssuedCommand(command=command, t_issued=now,
                               reply_timeout_s=self.reply_timeout_s, targets=set(self.drones))
        replaced = verb in ("start", "end") and self._supersede_pending(issued, now=now)
        self.commands[command.command_id] = issued
        if replaced:
            self.t_start, self.t_end = self._bounds()
        elif verb == "start":
            self.t_start, self.t_end = t_exec, None
        elif verb == "end":
            self.t_end = t_exec
        else:
            self.params.update(args or {})
        self.changes += 1
        # Keep memory bounded: forget commands long past their execution, except those
        # that make the mission's state (a drone that rejoins gets them again).
        keep = {id(i) for i in self.state_commands()}
        for cid in [c for c, i in self.commands.items()
                    if now - 3600.0 > self._until(i) and id(i) not in keep]:
            del self.commands[cid]
        return issued

    def _supersede_pending(self, issued: IssuedCommand, *, now: float) -> bool:
        """The operator's latest start or end decides from its time on: one issued earlier
        that has not run yet and would run at or after it is replaced (not sent any more;
        a drone that has it skips it, ``companion.commands``). Returns whether any was.
        Before, both ran at their own times: an end sent while a start was scheduled ran
        first and the start after it (the fleet streamed; the report had t_end < t_start),
        and a start after a scheduled end was ended by it (the station said running)."""
        t_exec = issued.command.t_exec
        replaced = False
        for earlier in self.commands.values():
            c = earlier.command
            if c.name in ("start", "end") and earlier.superseded_by is None \
                    and c.t_exec > now and c.t_exec >= t_exec:
                earlier.superseded_by = issued.command.command_id
                replaced = True
        return replaced

    def _bounds(self) -> tuple[float | None, float | None]:
        """(t_start, t_end) from the start and end commands that were not replaced."""
        t_start: float | None = None
        t_end: float | None = None
        for issued in self.commands.values():
            c = issued.command
            if issued.superseded_by is not None:
                continue
            if c.name == "start":
                t_start, t_end = c.t_exec, None
            elif c.name == "end" and t_start is not None and t_end is None:
                t_end = c.t_exec
        return t_start, t_end

    def _take_id(self) -> int:
        cid = self._next_id
        self._next_id = cid + 1 if cid + 1 < 2**32 else 1
        return cid

    def on_status(
        self,
        drone: str,
        *,
        state: str,
        command_id: int | None,
        now: float,
        info: Mapping[str, Any] | None = None,
    ) -> IssuedCommand | None:
        """A STATUS from a drone: an ack (with a command id) and/or a named report."""
        self.on_drone_heard(drone, now=now)
        if command_id is not None:
            issued = self.commands.get(command_id)
            if issued is not None:
                self.changes += 1
                issued.acked.setdefault(drone, now)
                if state in FINAL:
                    issued.results[drone] = {"state": state, "t": now, "info": dict(info or {})}
                if drone not in issued.results or state in FINAL:  # a late ack never undoes
                    issued.states[drone] = state
            return issued
        # An unsolicited status is repeated while it holds; a report is a change of it
        # (e.g. running -> done), counted once.
        if self.last_state.get(drone) != state:
            self.last_state[drone] = state
            self.on_report(drone, state, now=now)
        return None

    def resend_to(self, drone: str) -> None:
        """Send ``drone`` its unacknowledged commands at the next :meth:`due` (it restarted)."""
        for issued in self.commands.values():
            if drone not in issued.acked:
                issued.last_sent.pop(drone, None)

    def state_commands(self) -> list[IssuedCommand]:
        """The commands that make the mission's state, in issue order: the latest start,
        every end after it, and of the last :data:`PARAMS_KEPT` set_params those with a key
        no later one sets (a rejected one, all or nothing, sets none)."""
        issued = [c for c in self.commands.values() if c.superseded_by is None]
        starts = [i for i, c in enumerate(issued) if c.command.name == "start"]
        first = starts[-1] if starts else len(issued)
        params: list[IssuedCommand] = []
        later: set[str] = set()
        for c in reversed([c for c in issued if c.command.name == "set_params"][-PARAMS_KEPT:]):
            keys = set(c.command.args)
            if not keys <= later:
                params.append(c)
            if not any(r["state"] == "error" for r in c.results.values()):
                later |= keys
        return [c for i, c in enumerate(issued) if any(c is p for p in params) or (
            i >= first and c.command.name in ("start", "end"))]

    def rejoin(self, drone: str, *, now: float) -> int:
        """``drone`` lost what it was told (it restarted): send it the commands of
        :meth:`state_commands` again, as new for it, with their ids (a drone that did not
        restart answers a repeat with its result; a restarted one executes it at once, its
        ``t_exec`` being past). One on its way to the drone is left alone. Returns how many
        were armed again."""
        return self._arm_again(drone, now=now, forget_answers=True)

    def catch_up(self, drone: str, *, now: float) -> int:
        """``drone`` is heard again after a link loss: the commands of
        :meth:`state_commands` it has no result for are sent to it again, even those
        expired meanwhile (a set_params issued during a 40 s outage never reached the drones,
        which showed ``no reply`` for good). Returns how many were armed again."""
        return self._arm_again(drone, now=now, forget_answers=False)

    def _arm_again(self, drone: str, *, now: float, forget_answers: bool) -> int:
        armed = 0
        for issued in self.state_commands():
            if self._on_its_way(issued, drone, now) or (
                    not forget_answers and drone in issued.results):
                continue
            if forget_answers:
                for table in (issued.acked, issued.states, issued.results, issued.first_sent,
                              issued.last_sent):
                    table.pop(drone, None)
            issued.rejoined[drone] = now
            issued.targets.add(drone)
            armed += 1
        if armed:
            self.changes += 1
        return armed

    def on_mission_state(self, drone: str, state: str, *, t_gen: float, now: float) -> int:
        """A drone says where its mission window is (``idle``, ``running``, ``ended``): one
        that runs no mission while ours runs (restarted, or joined after the start's
        ``command_ttl_s``), or runs one we ended, rejoins. Returns the commands armed."""
        phase = self.phase(now=now)
        if not ((phase == "running" and state != "running")
                or (phase == "ended" and state == "running")):
            return 0
        decisive = [c for c in self.state_commands() if c.command.name in ("start", "end")]
        if phase == "ended":
            decisive = [c for c in decisive if c.command.name == "end"]
        if not decisive:
            return 0
        command = decisive[-1] if phase == "ended" else decisive[0]
        result = command.results.get(drone)
        if result is None:
            if self._on_its_way(command, drone, now) or drone in command.rejoined:
                return 0  # on its way, or sent again once already without an answer
        elif t_gen <= result["t"] + STATUS_AFTER_RESULT_S:
            return 0  # said before it executed the command
        if now - self._contradicted.get(drone, -math.inf) < CONTRADICTED_RETRY_S:
            return 0
        self._contradicted[drone] = now
        return self.rejoin(drone, now=now)

    def on_report(self, drone: str, name: str, *, now: float) -> None:
        self.changes += 1
        self.report_counts[name] += 1
        self.report_drones.setdefault(name, set()).add(drone)

    def reset_reports(self) -> None:
        self.changes += 1
        self.report_counts.clear()
        self.report_drones.clear()

    # -- outputs ------------------------------------------------------------------------
    def _live(self, issued: IssuedCommand, now: float) -> bool:
        """Still sent to some drone."""
        return issued.superseded_by is None and now <= self._until(issued)

    def _until(self, issued: IssuedCommand) -> float:
        return max([issued.command.t_exec, *issued.rejoined.values()]) + self.command_ttl_s

    def _expiry(self, issued: IssuedCommand, drone: str) -> float:
        """Until when ``issued`` is sent to ``drone``."""
        return max(issued.command.t_exec,
                   issued.rejoined.get(drone, -math.inf)) + self.command_ttl_s

    def _live_for(self, issued: IssuedCommand, drone: str, now: float) -> bool:
        return issued.superseded_by is None and now <= self._expiry(issued, drone)

    def _on_its_way(self, issued: IssuedCommand, drone: str, now: float) -> bool:
        """Sent (or armed again) to ``drone``, no result yet, still being resent."""
        return (drone not in issued.results and self._live_for(issued, drone, now)
                and (drone in issued.last_sent or drone in issued.rejoined))

    def _next_send(self, issued: IssuedCommand, drone: str) -> float | None:
        """When ``drone`` should get ``issued`` next: until acknowledged every ``retry_s``;
        acknowledged but without a result, again from one ``retry_s`` after ``t_exec``."""
        if drone in issued.results:
            return None
        last = issued.last_sent.get(drone)
        if last is None:
            return issued.t_issued
        if drone in issued.acked:
            return max(last, issued.command.t_exec) + self.retry_s
        return last + self.retry_s

    def due(self, *, now: float) -> list[tuple[str, Command]]:
        """(drone, command) pairs to send now; marks them sent."""
        out: list[tuple[str, Command]] = []
        for issued in self.commands.values():
            if not self._live(issued, now):
                continue
            for drone in self.drones:
                if not self._live_for(issued, drone, now):
                    continue
                issued.targets.add(drone)
                t = self._next_send(issued, drone)
                if t is not None and now >= t:
                    issued.first_sent.setdefault(drone, now)
                    issued.last_sent[drone] = now
                    out.append((drone, issued.command))
        return out

    def get_timer(self) -> float | None:
        """Next time :meth:`due` has something to send, or None."""
        deadline: float | None = None
        for issued in self.commands.values():
            if issued.superseded_by is not None:
                continue
            for drone in self.drones:
                expiry = self._expiry(issued, drone)
                t = self._next_send(issued, drone)
                if t is not None and t <= expiry and (deadline is None or t < deadline):
                    deadline = t
        return deadline

    def phase(self, *, now: float) -> str:
        if self.t_start is None:
            return "idle"
        if self.t_end is not None and now >= self.t_end and self.t_end >= self.t_start:
            return "ended"
        return "scheduled" if now < self.t_start else "running"

    def state(self, *, now: float, last_commands: int = 20) -> dict[str, Any]:
        """Phase, times, parameters (in effect, and those every drone rejected), drones,
        reports and the last commands with results."""
        params = fleet_params(
            (dict(i.command.args), [e["result"] for e in i.outcome(now)["results"].values()])
            for i in self.commands.values() if i.command.name == "set_params")
        return {
            "phase": self.phase(now=now),
            "t_start": self.t_start,
            "t_end": self.t_end,
            "params": params.in_effect,
            "params_rejected": params.rejected,
            "drones": sorted(self.drones),
            "reports": dict(self.report_counts),
            "report_drones": {k: sorted(v) for k, v in self.report_drones.items()},
            "commands": [
                i.as_json(now) for i in list(self.commands.values())[-last_commands:]
            ],
        }
