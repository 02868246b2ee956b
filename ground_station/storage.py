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
"""

from __future__ import annotations

import contextlib
import errno
import json
import math
import os
import re
import sqlite3
from collections.abc import Iterable, Iterator, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from utility_specs.log import message_to_record
from utility_specs.message import Message

__all__ = ["BatchResult", "ImageRow", "Storage", "StoreItem", "log_record"]

SCHEMA = """
CREATE TABLE IF NOT EXISTS missions (
    name TEXT PRIMARY KEY,
    t_created REAL NOT NULL,
    t_start REAL,
    t_end REAL
);
CREATE TABLE IF NOT EXISTS messages (
    id INTEGER PRIMARY KEY,
    mission TEXT NOT NULL,
    sender TEXT NOT NULL,
    seq INTEGER NOT NULL,
    type TEXT NOT NULL,
    t_gen REAL NOT NULL,
    t_sent REAL,
    t_rcv REAL NOT NULL,
    size INTEGER NOT NULL,
    version INTEGER,
    data TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS messages_by_sender ON messages (mission, sender, t_rcv);
CREATE TABLE IF NOT EXISTS images (
    id INTEGER PRIMARY KEY,
    mission TEXT NOT NULL,
    sender TEXT NOT NULL,
    seq INTEGER NOT NULL,
    type TEXT NOT NULL,
    t_gen REAL NOT NULL,
    t_rcv REAL NOT NULL,
    size INTEGER NOT NULL,
    version INTEGER,
    red REAL,
    object INTEGER NOT NULL DEFAULT 0,
    utility REAL NOT NULL,
    lat_deg REAL, lon_deg REAL, alt_m REAL,
    x_m REAL, y_m REAL,
    roll_deg REAL, pitch_deg REAL, yaw_deg REAL,
    path TEXT,
    error TEXT,
    pose_age_s REAL,
    pose TEXT,
    UNIQUE (mission, sender, seq)
);
CREATE INDEX IF NOT EXISTS images_by_sender ON images (mission, sender, t_rcv);
CREATE INDEX IF NOT EXISTS images_by_utility ON images (mission, utility);
CREATE TABLE IF NOT EXISTS alerts (
    id INTEGER PRIMARY KEY,
    mission TEXT NOT NULL,
    t REAL NOT NULL,
    level TEXT NOT NULL,
    kind TEXT NOT NULL,
    drone TEXT,
    text TEXT NOT NULL
);
"""

FILE_WRITERS = 8
"""Threads writing image files of one batch in parallel."""

_SAFE = re.compile(r"[^A-Za-z0-9_.-]")


def safe_name(name: str) -> str:
    """A sender or mission id usable as one path component."""
    cleaned = _SAFE.sub("_", name)[:64]
    return cleaned if cleaned not in ("", ".", "..") else "_"


def _jsonable(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, str | int | float | bool) or value is None:
        return value
    return str(value)


def log_record(message: Message) -> dict[str, Any]:
    """One mission-log line (the JSON Lines contract read by ``uav-utility evaluate``)."""
    record = message_to_record(message)
    record["data"] = _jsonable(record["data"])
    return record


@dataclass(frozen=True, slots=True, kw_only=True)
class StoreItem:
    """One received message to persist; ``payload`` is set for images."""

    mission: str
    message: Message
    payload: bytes | None = None
    utility: float | None = None
    """Image utility weight (eq. 7.1/7.2); only for images."""
    t_rcv: float | None = None
    """The link's reception time, unclamped (for the receiver report's entry)."""


@dataclass(slots=True, kw_only=True)
class BatchResult:
    image_ids: list[int | None] = field(default_factory=list)
    """Per item, the images.id row (None for telemetry or when the row failed)."""
    errors: list[str] = field(default_factory=list)
    """Human-readable storage errors (e.g. disk full) raised while writing this batch."""
    images_stored: int = 0
    """Image files that reached the disk."""
    stored: list[bool] = field(default_factory=list)
    """Per item, True when it is durable: its row committed and, for an image, its file
    written under its final name. Only these may be reported delivered."""


@dataclass(frozen=True, slots=True, kw_only=True)
class ImageRow:
    id: int
    mission: str
    sender: str
    seq: int
    type: str
    t_gen: float
    t_rcv: float
    size: int
    version: int | None
    red: float | None
    object: bool
    utility: float
    lat_deg: float | None
    lon_deg: float | None
    alt_m: float | None
    x_m: float | None
    y_m: float | None
    roll_deg: float | None
    pitch_deg: float | None
    yaw_deg: float | None
    path: str | None
    error: str | None
    pose_age_s: float | None = None
    """How old the position was when the image was taken (None: not reported)."""
    pose: str | None = None
    """``ok``, ``stale`` (older than POSE_STALE_AFTER_S) or ``none`` (no fix: no position)."""

    def as_json(self) -> dict[str, Any]:
        return {name: getattr(self, name) for name in self.__dataclass_fields__}


POSE_STALE_AFTER_S = 1.0
"""An image's position older than this (5 samples at the companion's 5 Hz) is stale: an
autopilot outage, not the geotag of the place the image shows."""
_NEW_IMAGE_COLUMNS = (("pose_age_s", "REAL"), ("pose", "TEXT"))


def pose_quality(data: Mapping[str, Any]) -> tuple[float | None, str]:
    """(pose age, ``ok``/``stale``/``none``) of an image's geotag data."""
    age = _geo(data, "pose_age_s")
    lat, lon = _geo(data, "lat_deg", "lat"), _geo(data, "lon_deg", "lon")
    if data.get("position") == "none" or lat is None or lon is None \
            or (abs(lat) < 1e-6 and abs(lon) < 1e-6):
        return age, "none"
    if age is not None and age > POSE_STALE_AFTER_S:
        return age, "stale"
    return age, "ok"


def _geo(data: Mapping[str, Any], *keys: str) -> float | None:
    for key in keys:
        value = data.get(key)
        if isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value):
            return float(value)
    return None


def _angle_deg(data: Mapping[str, Any], *keys: str, radians: str) -> float | None:
    """An attitude angle in degrees; the companion's geotags carry MAVLink's radians."""
    value = _geo(data, *keys)
    if value is not None:
        return value
    rad = _geo(data, radians)
    return math.degrees(rad) if rad is not None else None


def _fsync_dir(directory: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


class Storage:
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
            self.removed_temp_files = self._remove_temp_files()
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
        for name, kind in _NEW_IMAGE_COLUMNS:
            if name not in have:
                self.db.execute(f"ALTER TABLE images ADD COLUMN {name} {kind}")

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
                self.mark_mission(mission, now=t_end, t_end=t_end)
        self._last_rcv.clear()
        for handle in self._logs.values():
            with contextlib.suppress(OSError):
                handle.close()
        self._logs.clear()
        self.db.close()

    # -- writing ------------------------------------------------------------------------
    def image_relpath(self, mission: str, message: Message) -> Path:
        version = "" if message.version is None else f"-v{message.version}"
        return (
            Path("missions")
            / safe_name(mission)
            / "images"
            / safe_name(message.sender)
            / f"{message.seq:09d}{version}.jpg"
        )

    def _remove_temp_files(self) -> int:
        """Half-written images of a process that died mid-write (``.NAME.jpg.tmp``): never
        indexed, never under a final name, only taking space. Runs when a writer opens."""
        removed = 0
        for tmp in (self.root / "missions").glob("*/images/*/.*.tmp"):
            with contextlib.suppress(OSError):
                tmp.unlink()
                removed += 1
        return removed

    def _write_file(self, relpath: Path, payload: bytes) -> None:
        final = self.root / relpath
        folder = final.parent
        if folder not in self._made_dirs:
            folder.mkdir(parents=True, exist_ok=True)
            self._made_dirs.add(folder)
        tmp = final.with_name(f".{final.name}.tmp")
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        except FileNotFoundError:  # the folder was removed while running: make it again
            self._made_dirs.discard(folder)
            folder.mkdir(parents=True, exist_ok=True)
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        try:
            view = memoryview(payload)
            while view:
                written = os.write(fd, view)
                view = view[written:]
            if self.fsync:
                os.fsync(fd)
        except BaseException:
            os.close(fd)
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise
        os.close(fd)
        os.replace(tmp, final)

    def _sync_dirs(self, dirs: set[Path]) -> None:
        """Make the batch's renames durable. In parallel, like the files: a batch from 50
        drones touches 50 folders, and 50 fsyncs one after another took longer than the
        batch's files."""
        if self.fsync:
            list(self._files.map(_fsync_dir, dirs))

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

    def _store_file(self, item: StoreItem) -> tuple[Path | None, str | None]:
        """Write one image file; (relative path, None) or (None, error text)."""
        if item.payload is None:
            return None, None
        rel = self.image_relpath(item.mission, item.message)
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
        outcomes = list(self._files.map(self._store_file, items))
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
                    self.mark_mission(item.mission, now=now, t_start=t_start)
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
            data_json = json.dumps(_jsonable(m.data))
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
                " pitch_deg, yaw_deg, path, error, pose_age_s, pose)"
                " VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?)",
                (
                    item.mission,
                    m.sender,
                    m.seq,
                    m.type,
                    m.t_gen,
                    t_rcv,
                    m.size,
                    m.version,
                    _geo(d, "red"),
                    1 if obj is True or obj == 1 else 0,
                    item.utility,
                    _geo(d, "lat_deg", "lat") if placed else None,
                    _geo(d, "lon_deg", "lon") if placed else None,
                    _geo(d, "alt_m", "alt_rel_m", "alt") if placed else None,
                    _geo(d, "x_m", "x") if placed else None,
                    _geo(d, "y_m", "y") if placed else None,
                    _angle_deg(d, "roll_deg", "roll", radians="roll_rad"),
                    _angle_deg(d, "pitch_deg", "pitch", radians="pitch_rad"),
                    _angle_deg(d, "yaw_deg", "yaw", "heading_deg", radians="yaw_rad"),
                    path,
                    error,
                    pose_age,
                    pose,
                ),
            )
            ids.append(cur.lastrowid)
        cur.execute("COMMIT")
        return ids

    def write_alerts(self, rows: Sequence[tuple[str, float, str, str, str | None, str]]) -> None:
        """Store alerts: (mission, t, level, kind, drone, text) rows."""
        self.db.executemany(
            "INSERT INTO alerts (mission, t, level, kind, drone, text) VALUES (?,?,?,?,?,?)",
            rows,
        )

    def mark_mission(
        self, mission: str, *, now: float, t_start: float | None = None, t_end: float | None = None
    ) -> None:
        """Record a mission's start/end; an end also goes to the mission log as ``t_end``."""
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
            handle = self._log(mission)
            handle.write(json.dumps({"mission": bounds}) + "\n")
            handle.flush()

    # -- reading ------------------------------------------------------------------------
    def images(
        self,
        mission: str,
        *,
        sender: str | None = None,
        object_only: bool | None = None,
        order: str = "utility",
        limit: int = 50,
    ) -> list[ImageRow]:
        """Stored images of a mission, best first (``order='utility'``) or newest first."""
        where = ["mission = ?", "path IS NOT NULL"]
        args: list[Any] = [mission]
        if sender is not None:
            where.append("sender = ?")
            args.append(sender)
        if object_only is not None:
            where.append("object = ?")
            args.append(1 if object_only else 0)
        by = "utility DESC, t_rcv DESC" if order == "utility" else "t_rcv DESC"
        sql = f"SELECT * FROM images WHERE {' AND '.join(where)} ORDER BY {by} LIMIT ?"
        args.append(max(1, min(int(limit), 1000)))
        return [self._row(r) for r in self.db.execute(sql, args)]

    def window_share(
        self, mission: str, row: ImageRow, senders: Iterable[str], *, window_s: float
    ) -> float | None:
        """The sender's share of the bytes received from ``senders`` in the ``window_s``
        before ``row`` arrived (the tile's goodput share at that moment); None: nothing."""
        names = sorted({*senders, row.sender})
        sql = ("SELECT sender, SUM(size) FROM messages WHERE mission = ? AND sender IN"
               f" ({', '.join('?' * len(names))}) AND t_rcv > ? AND t_rcv <= ? GROUP BY sender")
        sums = dict(self.db.execute(sql, (mission, *names, row.t_rcv - window_s, row.t_rcv)))
        total = sum(v or 0 for v in sums.values())
        return (sums.get(row.sender) or 0) / total if total > 0 else None

    def iter_images(self, mission: str) -> Iterator[ImageRow]:
        for r in self.db.execute(
            "SELECT * FROM images WHERE mission = ? ORDER BY t_gen, sender, seq", (mission,)
        ):
            yield self._row(r)

    def image(self, image_id: int) -> ImageRow | None:
        row = self.db.execute("SELECT * FROM images WHERE id = ?", (image_id,)).fetchone()
        return self._row(row) if row is not None else None

    def latest_images(self, mission: str) -> list[ImageRow]:
        rows = self.db.execute(
            "SELECT * FROM images WHERE id IN (SELECT MAX(id) FROM images WHERE mission = ?"
            " AND path IS NOT NULL GROUP BY sender)",
            (mission,),
        )
        return [self._row(r) for r in rows]

    def missions(self) -> list[dict[str, Any]]:
        rows = self.db.execute(
            "SELECT m.name, m.t_created, m.t_start, m.t_end,"
            " (SELECT COUNT(*) FROM images i WHERE i.mission = m.name) AS images,"
            " (SELECT COUNT(*) FROM messages g WHERE g.mission = m.name) AS messages"
            " FROM missions m ORDER BY m.t_created"
        )
        return [dict(r) for r in rows]

    def counts(self, mission: str) -> dict[str, int]:
        images = self.db.execute(
            "SELECT COUNT(*), COUNT(path) FROM images WHERE mission = ?", (mission,)
        ).fetchone()
        messages = self.db.execute(
            "SELECT COUNT(*) FROM messages WHERE mission = ?", (mission,)
        ).fetchone()
        return {"images": images[0], "images_on_disk": images[1], "messages": messages[0]}

    def telemetry(
        self, mission: str, *, sender: str | None = None, limit: int = 200
    ) -> list[dict[str, Any]]:
        where, args = "mission = ?", [mission]
        if sender is not None:
            where += " AND sender = ?"
            args.append(sender)
        rows = self.db.execute(
            f"SELECT sender, seq, type, t_gen, t_rcv, size, data FROM messages WHERE {where}"
            " ORDER BY id DESC LIMIT ?",
            [*args, limit],
        )
        return [{**dict(r), "data": json.loads(r["data"])} for r in rows]

    def alerts(self, mission: str, *, limit: int = 100) -> list[dict[str, Any]]:
        rows = self.db.execute(
            "SELECT t, level, kind, drone, text FROM alerts WHERE mission = ?"
            " ORDER BY id DESC LIMIT ?",
            (mission, limit),
        )
        return [dict(r) for r in rows]

    @staticmethod
    def _row(r: sqlite3.Row) -> ImageRow:
        values = dict(r)
        values["object"] = bool(values["object"])
        return ImageRow(**values)
