"""The mission manager's state on disk, so a restarted station still knows its mission.

Before this a restart mid-mission showed the phase ``idle``, and the start, the parameters
and every command's results the drones had acknowledged were gone (the drones kept
running): the operator saw no mission, and a drone that restarted later was never told to
start. ``DATA_DIR/mission_state.json`` holds the phase's times, the parameters, the report
counts, the commands with their per-drone acks and results, and the drones heard (not
"joined" again after a restart). It is rewritten (atomically)
after every command the API accepts, before the API answers, then once a second while
anything changed, and at shutdown.
"""

from __future__ import annotations

import asyncio
import logging
import math
import threading
from collections import Counter
from pathlib import Path
from typing import Any

from companion.protocol.records import Command
from ground_station.json_state import load_json_state, save_json_state
from ground_station.missions import IssuedCommand, MissionManager

__all__ = ["MissionStateFile", "MissionStateKeeper", "restore_missions", "snapshot_missions"]

log = logging.getLogger(__name__)

VERSION = 1
MAX_DRONES = 1024
"""Drones remembered across restarts (the receiver's reports forget beyond as many)."""
PER_DRONE = ("first_sent", "last_sent", "acked", "states", "results", "rejoined")


def snapshot_missions(missions: MissionManager, mission: str) -> dict[str, Any]:
    """Everything a restarted station needs to show and continue ``mission`` (JSON)."""
    commands = []
    for issued in missions.commands.values():
        c = issued.command
        commands.append({
            "command_id": c.command_id, "name": c.name, "t_exec": c.t_exec,
            "args": dict(c.args), "target": c.target, "t_issued": issued.t_issued,
            "targets": sorted(issued.targets), "superseded_by": issued.superseded_by,
            **{name: dict(getattr(issued, name)) for name in PER_DRONE},
        })
    return {
        "version": VERSION, "mission": mission,
        "t_start": missions.t_start, "t_end": missions.t_end,
        "params": dict(missions.params), "next_id": missions._next_id,
        "reports": dict(missions.report_counts),
        "report_drones": {k: sorted(v) for k, v in missions.report_drones.items()},
        "commands": commands,
        "drones": sorted(set(missions.drones) | missions.heard_before)[-MAX_DRONES:],
    }


def _time(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float) \
            or not math.isfinite(value):
        return None
    return float(value)


def restore_missions(missions: MissionManager, saved: dict[str, Any], mission: str) -> int:
    """Load a :func:`snapshot_missions` of ``mission`` into a fresh manager; returns the
    commands restored. Another mission's state is not loaded (a station started with a new
    ``--mission`` must not show, or send a rejoining drone, the old one's start). A damaged
    entry is skipped, never fatal."""
    if saved.get("version") != VERSION:
        return 0
    if saved.get("mission") != mission:
        log.info("mission state of %r not restored: this run's mission is %r",
                 saved.get("mission"), mission)
        return 0
    missions.t_start, missions.t_end = _time(saved.get("t_start")), _time(saved.get("t_end"))
    if isinstance(saved.get("params"), dict):
        missions.params = dict(saved["params"])
    if isinstance(saved.get("reports"), dict):
        missions.report_counts = Counter({str(k): int(v) for k, v in saved["reports"].items()
                                          if isinstance(v, int)})
    if isinstance(saved.get("report_drones"), dict):
        missions.report_drones = {str(k): {str(d) for d in v}
                                  for k, v in saved["report_drones"].items()
                                  if isinstance(v, list)}
    if isinstance(saved.get("drones"), list):
        missions.heard_before = {d for d in saved["drones"][:MAX_DRONES] if isinstance(d, str)}
    restored = 0
    for entry in saved.get("commands") or ():
        try:
            command = Command(command_id=int(entry["command_id"]), name=str(entry["name"]),
                              t_exec=float(entry["t_exec"]), args=dict(entry["args"]),
                              target=entry.get("target"))
            issued = IssuedCommand(command=command, t_issued=float(entry["t_issued"]),
                                   reply_timeout_s=missions.reply_timeout_s,
                                   targets=set(entry["targets"]))
            for name in PER_DRONE:
                getattr(issued, name).update(dict(entry[name]))
            if isinstance(entry.get("superseded_by"), int):
                issued.superseded_by = entry["superseded_by"]
        except (KeyError, TypeError, ValueError) as exc:
            log.warning("mission state: command entry skipped (%s)", exc)
            continue
        missions.commands[command.command_id] = issued
        restored += 1
    next_id = saved.get("next_id")
    if isinstance(next_id, int) and 0 < next_id < 2**32:  # ids never repeat across restarts
        missions._next_id = max(missions._next_id, next_id)
    if missions.commands:
        missions._next_id = max(missions._next_id, max(missions.commands) + 1) % (2**32 - 1)
    return restored


class MissionStateFile:
    """``DATA_DIR/mission_state.json``: read once at start, replaced atomically after."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._lock = threading.Lock()
        self._written = -1
        """The manager's ``changes`` count of the newest snapshot written: an older one that
        reaches the disk later (two writer threads) is not written over it."""

    def load(self) -> dict[str, Any]:
        """The saved snapshot, or {} (first start; a damaged file is logged, never fatal)."""
        return load_json_state(self.path, "mission state")

    def save(self, snapshot: dict[str, Any], changes: int) -> None:
        """Write ``snapshot`` (taken at ``changes``) unless a newer one is on disk already.
        Blocking (fsync): call it off the event loop, or at shutdown."""
        with self._lock:
            if changes <= self._written:
                return
            save_json_state(self.path, snapshot)
            self._written = changes


class MissionStateKeeper:
    """The station's link to its mission state file: restore at open, then save now (an
    accepted command, off the loop), soon (from the once-a-second tick, while anything
    changed) and at close (blocking). A failing disk is counted and logged, never fatal."""

    def __init__(self, missions: MissionManager, mission: str, path: Path,
                 counters: Counter[str]) -> None:
        self.missions = missions
        self.mission = mission
        self.file = MissionStateFile(path)
        self.counters = counters
        self._saved = 0

    async def restore(self) -> int:
        saved = await asyncio.to_thread(self.file.load)
        return restore_missions(self.missions, saved, self.mission) if saved else 0

    async def save_now(self) -> None:
        await asyncio.to_thread(self._write, self._snapshot(), self.missions.changes)

    def save_soon(self) -> None:
        if self.missions.changes == self._saved:
            return
        self._saved = self.missions.changes
        asyncio.get_running_loop().run_in_executor(None, self._write, self._snapshot(),
                                                   self.missions.changes)

    def save_blocking(self) -> None:
        self._write(self._snapshot(), self.missions.changes)

    def _snapshot(self) -> dict[str, Any]:
        return snapshot_missions(self.missions, self.mission)

    def _write(self, snapshot: dict[str, Any], changes: int) -> None:
        try:
            self.file.save(snapshot, changes)
        except OSError as exc:
            self.counters["mission_state_errors"] += 1
            if self.counters["mission_state_errors"] % 60 == 1:  # once a minute at most
                log.warning("mission state not saved (%d times): %s",
                            self.counters["mission_state_errors"], exc)
