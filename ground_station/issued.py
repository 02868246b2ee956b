"""A fleet command as the station issued it, and what each drone made of it.

Split from :mod:`ground_station.missions` (the mission manager) to keep each small.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from companion.protocol.records import Command

__all__ = ["FINAL", "NO_REPLY", "SUPERSEDED", "IssuedCommand"]

FINAL = ("done", "error")
"""Drone states that end a command (a STATUS naming its id)."""
NO_REPLY = "no reply"
SUPERSEDED = "superseded"
"""A start or end replaced, before it ran, by a later one (:attr:`IssuedCommand.superseded_by`)."""


@dataclass(slots=True, kw_only=True)
class IssuedCommand:
    """A command and, per drone, when it was sent, acknowledged and what came of it."""

    command: Command
    t_issued: float
    reply_timeout_s: float = 5.0
    targets: set[str] = field(default_factory=set)
    """Drones the command is for: those known when issued and those heard while it is live."""
    first_sent: dict[str, float] = field(default_factory=dict)
    last_sent: dict[str, float] = field(default_factory=dict)
    acked: dict[str, float] = field(default_factory=dict)
    states: dict[str, str] = field(default_factory=dict)
    results: dict[str, dict[str, Any]] = field(default_factory=dict)
    """Drone -> ``{"state": "done"|"error", "t": ..., "info": {...}}`` from its final STATUS."""
    rejoined: dict[str, float] = field(default_factory=dict)
    """Drone -> when the command was armed for it again (:meth:`MissionManager.rejoin`); it
    is sent to that drone until ``command_ttl_s`` after that."""
    superseded_by: int | None = None
    """The id of a later start or end issued before this one ran: it is not sent any more,
    and a drone that has it skips it (``companion.commands``)."""

    def reply_deadline(self, drone: str) -> float:
        """When a drone without a result counts as ``no reply``."""
        t0 = max(self.command.t_exec, self.first_sent.get(drone, self.command.t_exec))
        return t0 + self.reply_timeout_s

    def result(self, drone: str, now: float | None) -> str:
        """``done``, ``error``, ``no reply``, or while waiting ``acked``/``sent``/``pending``."""
        final = self.results.get(drone)
        if final is not None and not (self.superseded_by and final["state"] == "error"):
            return str(final["state"])
        if self.superseded_by is not None:
            return SUPERSEDED
        if now is not None and now >= self.reply_deadline(drone):
            return NO_REPLY
        if drone in self.acked:
            return "acked"
        return "sent" if drone in self.last_sent else "pending"

    def outcome(self, now: float | None) -> dict[str, Any]:
        """Per drone result (with the reason of an error) and their counts."""
        drones = sorted(self.targets | set(self.last_sent) | set(self.acked))
        per_drone: dict[str, dict[str, Any]] = {}
        counts = {"done": 0, "error": 0, NO_REPLY: 0, "waiting": 0}
        for drone in drones:
            result = self.result(drone, now)
            entry: dict[str, Any] = {"result": result}
            final = self.results.get(drone)
            if final is not None:
                entry["info"] = final["info"]
                if result == "error":
                    entry["reason"] = str(final["info"].get("error", "no reason given"))
            elif result == SUPERSEDED:
                entry["reason"] = f"replaced by #{self.superseded_by} before it ran"
            elif result == NO_REPLY:
                entry["reason"] = (f"no result {self.reply_timeout_s:g} s after execution"
                                   + ("" if drone in self.acked else "; never acknowledged"))
            per_drone[drone] = entry
            if result == SUPERSEDED:
                counts[SUPERSEDED] = counts.get(SUPERSEDED, 0) + 1
            else:
                counts[result if result in counts else "waiting"] += 1
        return {"results": per_drone, "summary": {**counts, "total": len(drones)},
                "finished": counts["waiting"] == 0 and bool(drones)}

    def as_json(self, now: float | None = None) -> dict[str, Any]:
        c = self.command
        return {
            "command_id": c.command_id,
            "name": c.name,
            "t_exec": c.t_exec,
            "args": dict(c.args),
            "t_issued": self.t_issued,
            "sent_to": sorted(self.last_sent),
            "acked_by": sorted(self.acked),
            "states": dict(self.states),
            "superseded_by": self.superseded_by,
            **self.outcome(now),
        }
