"""Durable storage: image files written atomically, an SQLite (WAL) index, the mission log.

:class:`Storage` is synchronous and confined to the thread that calls it (the shell runs it in
one owned executor thread for writes and another for reads; WAL lets them run concurrently).
Image files are written to a temp file, fsync'd, then ``os.replace``'d into place, so a crash
never leaves half an image under its final name. A failing image write (full disk) is
reported in :class:`BatchResult` and the rest of the batch, telemetry included, still lands.

``BatchResult.stored`` says, per item, whether it is durable (its row committed and, for an
image, its file fsync'd under its final name): the receiver reports exactly those as
delivered (docs/ground_station.md, "What a receiver report promises"). An item the database
refuses (a value SQLite cannot hold) fails alone: a failed batch transaction is retried item
by item, so one poisoned message never takes its batch with it.

The schema and records are in :mod:`ground_station.storage_records`, the queries in
:mod:`ground_station.storage_reads`; this module keeps the writing (files, transactions, the
mission log) and re-exports the names its users import.
"""

from __future__ import annotations

import contextlib
import errno
import json
import sqlite3
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from ground_station.storage_files import fsync_dir, remove_temp_files, write_atomically
from ground_station.storage_identity import image_relpath, image_relpaths, key_images_by_t_gen
from ground_station.storage_reads import StorageReads
from ground_station.storage_records import (
    NEW_IMAGE_COLUMNS,
    POSE_STALE_AFTER_S,
    SCHEMA,
    BatchResult,
    ImageRow,
    StoreItem,
    angle_deg,
    geo_number,
    jsonable,
    log_record,
    pose_quality,
    safe_name,
)
from utility_specs.message import Message

__all__ = [
    "POSE_STALE_AFTER_S",
    "SCHEMA",
    "BatchResult",
    "ImageRow",
    "Storage",
    "StoreItem",
    "log_record",
    "pose_quality",
    "safe_name",
]

FILE_WRITERS = 8
"""Threads writing image files of one batch in parallel."""


class Storage(StorageReads):
    """SQLite index and files under ``root``. Not thread-safe: one thread per instance."""

    def __init__(self, root: Path, *, fsync: bool = True, readonly: bool = False) -> None:
        self.root = Path(root)
        self.fsync = fsync
        self.root.mkdir(parents=True, exist_ok=True)
        self.db_path = self.root / "ground_station.sqlite3"
        self.db = sqlite3.connect(self.db_path, check_same_thread=False, isolation_level=None)
        self.db.row_factory = sqlite3.Row
        self.db.execute("PRAGMA busy_timeout = 5000")
        self.removed_temp_files = 0
        if not readonly:
            self.db.execute("PRAGMA journal_mode = WAL")
            self.db.execute("PRAGMA synchronous = NORMAL")
            self.db.executescript(SCHEMA)
            self._add_columns()
            self.removed_temp_files = remove_temp_files(self.root)
        self._logs: dict[str, Any] = {}
        self._files = ThreadPoolExecutor(FILE_WRITERS, thread_name_prefix="gs-image-file")
        self._made_dirs: set[Path] = set()
        """Image folders this process created or found: no mkdir syscall per image (about
        50 us of kernel time each on the 2-core test machine, 500 times a second)."""
        self._last_rcv: dict[str, float] = {}
        """Per mission written to in this process, the newest t_rcv (for the log's t_end)."""
        self._ended: set[str] = set()
        """Missions whose end an operator command recorded in this process."""
        self._unbounded: dict[str, float] = {}
        """Missions whose opening ``t_start`` could not be recorded yet -> earliest t_gen."""

    def _add_columns(self) -> None:
        """Columns newer than a database made by an older version (nullable: old rows)."""
        have = {r[1] for r in self.db.execute("PRAGMA table_info(images)")}
        for name, kind in NEW_IMAGE_COLUMNS:
            if name not in have:
                self.db.execute(f"ALTER TABLE images ADD COLUMN {name} {kind}")
        key_images_by_t_gen(self.db)

    def close(self, *, now: float | None = None) -> None:
        """Close files. A mission received in this process without an end command gets
        ``t_end`` = the latest of its last reception, ``now`` and its start, so
        ``uav-utility evaluate`` has bounds."""
        self._files.shutdown(wait=True)
        for mission, t_rcv in self._last_rcv.items():
            if mission in self._ended:
                continue
            with contextlib.suppress(sqlite3.Error, OSError):
                row = self.db.execute(
                    "SELECT t_start FROM missions WHERE name = ?", (mission,)
                ).fetchone()
                t_end = max(t_rcv, now or t_rcv, row[0] if row and row[0] is not None else t_rcv)
                self.mark_mission(mission, now=t_end, t_end=t_end, stop=True)
        self._last_rcv.clear()
        for handle in self._logs.values():
            with contextlib.suppress(OSError):
                handle.close()
        self._logs.clear()
        self.db.close()

    # -- writing ------------------------------------------------------------------------
    def image_relpath(self, mission: str, message: Message, *, renamed: bool = False) -> Path:
        return image_relpath(mission, message, renamed=renamed)

    def _write_file(self, relpath: Path, payload: bytes) -> None:
        write_atomically(self.root / relpath, payload, fsync=self.fsync,
                         made_dirs=self._made_dirs)

    def _sync_dirs(self, dirs: set[Path]) -> None:
        """Make the batch's renames durable. In parallel, like the files: a batch from 50
        drones touches 50 folders, and 50 fsyncs one after another took longer than the
        batch's files."""
        if self.fsync:
            list(self._files.map(fsync_dir, dirs))

    def log_path(self, mission: str) -> Path:
        return self.root / "missions" / safe_name(mission) / "mission_log.jsonl"

    def _log(self, mission: str) -> Any:
        handle = self._logs.get(mission)
        if handle is None:
            path = self.log_path(mission)
            path.parent.mkdir(parents=True, exist_ok=True)
            handle = open(path, "a", encoding="utf-8")  # noqa: SIM115 - kept open, closed in close()
            self._logs[mission] = handle
        return handle

    def _store_file(self, item: StoreItem, rel: Path | None) -> tuple[Path | None, str | None]:
        """Write one image file; (relative path, None) or (None, error text)."""
        if item.payload is None or rel is None:
            return None, None
        try:
            self._write_file(rel, item.payload)
        except OSError as exc:
            reason = "disk full" if exc.errno in (errno.ENOSPC, errno.EDQUOT) else "I/O error"
            return None, (
                f"image {item.message.sender}/{item.message.seq} not stored: {reason} "
                f"({exc.strerror or exc}) in {self.root}"
            )
        except Exception as exc:  # one bad item fails alone
            return None, f"image {item.message.sender}/{item.message.seq} not stored: {exc!r}"
        return rel, None

    def write_batch(self, items: Sequence[StoreItem], *, now: float) -> BatchResult:
        """Persist received messages: files first, then one transaction, then the log lines."""
        result = BatchResult()
        paths: list[str | None] = []
        errors: list[str | None] = []
        dirs: set[Path] = set()
        # Files are written (and fsync'd) by a few threads at once: fsync waits for the
        # disk, and parallel fsyncs share journal commits (about 1.7x here).
        outcomes = list(self._files.map(self._store_file, items, image_relpaths(self.db, items)))
        for rel, failure in outcomes:
            if rel is None:
                paths.append(None)
                errors.append(failure)
                if failure is not None:
                    result.errors.append(failure)
                continue
            dirs.add((self.root / rel).parent)
            paths.append(str(rel))
            errors.append(None)
            result.images_stored += 1
        self._sync_dirs(dirs)
        result.image_ids, committed = self._index_isolating(items, paths, errors, result,
                                                            now=now)
        result.stored = [
            done and (item.payload is None or path is not None)
            for done, item, path in zip(committed, items, paths, strict=True)
        ]
        try:
            self._open_bounds(items, now=now)
        except Exception as exc:  # bounds are bookkeeping, the rows are in
            result.errors.append(f"mission bounds not stored: {exc}")
        try:
            for item, done in zip(items, committed, strict=True):
                if done:
                    self._log(item.mission).write(json.dumps(log_record(item.message)) + "\n")
            for handle in self._logs.values():
                handle.flush()
        except (OSError, ValueError, TypeError) as exc:
            result.errors.append(f"mission log write failed: {exc}")
        return result

    def _index_isolating(
        self,
        items: Sequence[StoreItem],
        paths: list[str | None],
        errors: list[str | None],
        result: BatchResult,
        *,
        now: float,
    ) -> tuple[list[int | None], list[bool]]:
        """Index the batch in one transaction; if that fails, item by item, so only the
        items the database refuses fail. Returns the image ids and, per item, whether its
        rows committed."""
        try:
            ids = self._index(items, paths, errors, now=now)
        except Exception as exc:  # any refusal (full disk, a value SQLite
            # cannot hold, a closed database) must leave the writer usable
            self._rollback()
            if len(items) == 1:
                result.errors.append(self._index_error(items[0], exc))
                return [None], [False]
        else:
            return ids, [True] * len(items)
        ids = []
        committed = []
        for item, path, error in zip(items, paths, errors, strict=True):
            try:
                ids += self._index([item], [path], [error], now=now)
                committed.append(True)
            except Exception as exc:  # as above, per item
                self._rollback()
                result.errors.append(self._index_error(item, exc))
                ids.append(None)
                committed.append(False)
        return ids, committed

    def _index_error(self, item: StoreItem, exc: Exception) -> str:
        m = item.message
        reason = "disk full" if "full" in str(exc) else f"{type(exc).__name__}: {exc}"
        return f"database write of {m.sender}/{m.seq} failed: {reason} ({self.db_path})"

    def _rollback(self) -> None:
        if self.db.in_transaction:
            with contextlib.suppress(sqlite3.Error):
                self.db.execute("ROLLBACK")

    def _open_bounds(self, items: Sequence[StoreItem], *, now: float) -> None:
        """A mission's first messages open it: ``t_start`` = earliest t_gen, unless an
        operator's start command already set one."""
        for item in items:
            m = item.message
            t_rcv = m.t_rcv if m.t_rcv is not None else now
            if item.mission not in self._last_rcv:
                row = self.db.execute(
                    "SELECT t_start FROM missions WHERE name = ?", (item.mission,)
                ).fetchone()
                if row is None or row[0] is None:
                    t_start = min(i.message.t_gen for i in items if i.mission == item.mission)
                    # an earlier batch whose bounds failed (full disk) may have started earlier
                    t_start = min(t_start, self._unbounded.get(item.mission, t_start))
                    self._unbounded[item.mission] = t_start
                    self.mark_mission(item.mission, now=now, t_start=t_start, opened=True)
                self._unbounded.pop(item.mission, None)
                self._last_rcv[item.mission] = t_rcv
            else:
                self._last_rcv[item.mission] = max(self._last_rcv[item.mission], t_rcv)

    def _index(
        self,
        items: Sequence[StoreItem],
        paths: list[str | None],
        errors: list[str | None],
        *,
        now: float,
    ) -> list[int | None]:
        ids: list[int | None] = []
        missions = {item.mission for item in items}
        cur = self.db.cursor()
        cur.execute("BEGIN")
        for mission in missions:
            cur.execute(
                "INSERT OR IGNORE INTO missions (name, t_created) VALUES (?, ?)", (mission, now)
            )
        for item, path, error in zip(items, paths, errors, strict=True):
            m = item.message
            t_rcv = m.t_rcv if m.t_rcv is not None else now
            data_json = json.dumps(jsonable(m.data))
            cur.execute(
                "INSERT INTO messages (mission, sender, seq, type, t_gen, t_sent, t_rcv, size,"
                " version, data) VALUES (?,?,?,?,?,?,?,?,?,?)",
                (
                    item.mission,
                    m.sender,
                    m.seq,
                    m.type,
                    m.t_gen,
                    m.t_sent,
                    t_rcv,
                    m.size,
                    m.version,
                    data_json,
                ),
            )
            if item.utility is None:
                ids.append(None)
                continue
            d = m.data
            obj = d.get("object")
            pose_age, pose = pose_quality(d)
            placed = pose != "none"  # never a 0/0 or a guess without a fix in the index
            cur.execute(
                "INSERT OR REPLACE INTO images (mission, sender, seq, type, t_gen, t_rcv, size,"
                " version, red, object, utility, lat_deg, lon_deg, alt_m, x_m, y_m, roll_deg,"
                " pitch_deg, yaw_deg, path, error, pose_age_s, pose, alt_amsl_m)"
                " VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?)",
                (
                    item.mission,
                    m.sender,
                    m.seq,
                    m.type,
                    m.t_gen,
                    t_rcv,
                    m.size,
                    m.version,
                    geo_number(d, "red"),
                    1 if obj is True or obj == 1 else 0,
                    item.utility,
                    geo_number(d, "lat_deg", "lat") if placed else None,
                    geo_number(d, "lon_deg", "lon") if placed else None,
                    geo_number(d, "alt_m", "alt_rel_m", "alt") if placed else None,
                    geo_number(d, "x_m", "x") if placed else None,
                    geo_number(d, "y_m", "y") if placed else None,
                    angle_deg(d, "roll_deg", "roll", radians="roll_rad"),
                    angle_deg(d, "pitch_deg", "pitch", radians="pitch_rad"),
                    angle_deg(d, "yaw_deg", "yaw", "heading_deg", radians="yaw_rad"),
                    path,
                    error,
                    pose_age,
                    pose,
                    geo_number(d, "alt_amsl_m") if placed else None,
                ),
            )
            ids.append(cur.lastrowid)
        cur.execute("COMMIT")
        return ids

    def reopen_mission(self, mission: str, *, now: float, t_start: float | None) -> bool:
        """A restarted station goes on with ``mission``: its start again in the log, so the
        interval ``uav-utility evaluate`` takes spans the restart (the shutdown wrote a
        ``t_end``), and a ``t_end`` at this process's stop. ``t_start``: the operator's start
        the mission state restored; None: the start recorded here, unless an operator's end
        came after it (a mission the station opened itself, with its first message, ended
        for good at the first restart). Returns whether it was reopened."""
        if t_start is None:
            kinds = [r[0] for r in self.db.execute(
                "SELECT kind FROM mission_bounds WHERE mission = ? ORDER BY rowid", (mission,))]
            row = self.db.execute("SELECT t_start FROM missions WHERE name = ?",
                                  (mission,)).fetchone()
            starts = [i for i, kind in enumerate(kinds) if kind in ("start", "open")]
            after_start = kinds[starts[-1] + 1:] if starts else []
            if "end" in after_start or not after_start or row is None or row[0] is None:
                return False  # ended by an operator, still open (a crash), or never opened
            t_start = float(row[0])
        self.mark_mission(mission, now=now, t_start=t_start)
        self._last_rcv.setdefault(mission, now)
        return True

    def cancel_starts(self, mission: str, t_starts: Sequence[float], *, now: float) -> None:
        """Operator's starts replaced before they ran (an end sent while one was scheduled):
        their bounds go, and the mission's are again those of the rows left, in the missions
        row and in the mission log (a ``cancelled`` record, then the run the start had
        replaced, if it was open). With no start left the next message opens the mission."""
        for t in t_starts:
            self.db.execute("DELETE FROM mission_bounds WHERE rowid = (SELECT max(rowid) FROM"
                            " mission_bounds WHERE mission = ? AND kind = 'start' AND t_start = ?)",
                            (mission, t))
        t_start = t_end = None
        start_kind = "start"
        for a, b, kind in self.db.execute("SELECT t_start, t_end, kind FROM mission_bounds "
                                          "WHERE mission = ? ORDER BY rowid", (mission,)):
            t_start, t_end, start_kind = (a, None, kind) if a is not None else (t_start, b,
                                                                                 start_kind)
        self.db.execute("UPDATE missions SET t_start = ?, t_end = ? WHERE name = ?",
                        (t_start, t_end, mission))
        handle = self._log(mission)
        for t in t_starts:
            handle.write(json.dumps({"mission": {"cancelled": t}}) + "\n")
        if t_start is not None and t_end is None:  # the run it had replaced there, open again
            handle.write(json.dumps({"mission": {"t_start": t_start, "kind": start_kind}}) + "\n")
        handle.flush()
        if t_start is None:
            self._last_rcv.pop(mission, None)

    def write_alerts(self, rows: Sequence[tuple[str, float, str, str, str | None, str]]) -> None:
        """Store alerts: (mission, t, level, kind, drone, text) rows."""
        self.db.executemany(
            "INSERT INTO alerts (mission, t, level, kind, drone, text) VALUES (?,?,?,?,?,?)",
            rows,
        )

    def mark_mission(
        self, mission: str, *, now: float, t_start: float | None = None,
        t_end: float | None = None, stop: bool = False, opened: bool = False,
    ) -> None:
        """Record a mission's start/end; an end also goes to the mission log as ``t_end``.
        ``stop``: the end is the station's shutdown, not an operator's end. ``opened``: the
        start is the station's own, at a mission's first message (an operator's start
        replaces it in the report; an operator's start while one runs goes on with it)."""
        self.db.execute(
            "INSERT OR IGNORE INTO missions (name, t_created) VALUES (?, ?)", (mission, now)
        )
        if t_start is not None:
            self.db.execute(
                "UPDATE missions SET t_start = ?, t_end = NULL WHERE name = ?", (t_start, mission)
            )
            self._ended.discard(mission)
        if t_end is not None:
            self.db.execute("UPDATE missions SET t_end = ? WHERE name = ?", (t_end, mission))
            self._ended.add(mission)
        if t_start is not None or t_end is not None:
            bounds = {"t_start": t_start} if t_start is not None else {"t_end": t_end}
            # every start and end, as the mission log has them (the row keeps the latest)
            kind = ("open" if opened else "start") if t_start is not None \
                else "stop" if stop else "end"
            self.db.execute("INSERT INTO mission_bounds (mission, t_start, t_end, kind) "
                            "VALUES (?, ?, ?, ?)", (mission, bounds.get("t_start"),
                                                    bounds.get("t_end"), kind))
            handle = self._log(mission)
            handle.write(json.dumps({"mission": {**bounds, "kind": kind}}) + "\n")
            handle.flush()
