"""The read side of :class:`~ground_station.storage.Storage`: the queries the dashboard,
the API and the export run (on the station's reader thread, a read-only connection).

A mixin, so ``Storage`` stays one object per connection while each file reads as one
responsibility (issue 14).
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterable, Iterator
from typing import Any

from ground_station.storage_records import ImageRow

__all__ = ["StorageReads"]


class StorageReads:
    """Queries over ``self.db`` (provided by ``Storage``)."""

    db: sqlite3.Connection

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
