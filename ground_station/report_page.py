"""The end-of-mission report: utility over time per drone, as a page and as a PNG.

Utility here is what the station received: the summed utility weight (eq. 7.1/7.2 times the
version's quality, the gallery's U) of each drone's images per ``bin_s`` of reception time.
``GET /report`` is the page, ``GET /api/report`` its numbers, ``GET /api/report.png`` the
plot, also written to ``DATA_DIR/missions/MISSION/utility.png`` when the station holds data
of that mission (a read never creates files for made-up names); ``uav-sitl fleet`` writes
the same PNG into its run folder at the end (:func:`write_png`).

Drawing is matplotlib's object-oriented API on a figure of its own (no ``pyplot``: its global
figure manager is not thread-safe), on at most :data:`RENDERS` threads of the report's own
pool; at most :data:`WAITING` more requests wait for one, the rest get 503 + Retry-After, so
no reader keeps the station's default thread pool (or its cores) drawing. The file is written
through a temp name and ``os.replace``: two renders of one mission never leave a torn PNG.
"""

from __future__ import annotations

import asyncio
import contextlib
import io
import itertools
import math
import os
import sqlite3
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any, TypeVar

from aiohttp import web

from ground_station.storage_records import safe_name

__all__ = ["RenderGate", "add_report_routes", "figure", "mission_runs", "render_png",
           "utility_series", "write_png"]

BIN_S = 5.0
MAX_BINS = 2000
"""Most bins a series has: a longer span widens the bins (whole multiples of ``bin_s``).
The span runs from the mission's stored start, which nothing bounded before 2026-11-24: a
start in 1970 made ``GET /api/report`` build 3.6e8 bins per drone (gigabytes, on a read)."""
RENDERS = 2
"""PNGs drawn at once (each takes a thread and most of a core for ~0.1-0.5 s)."""
WAITING = 4
"""Requests that may wait for a free renderer; beyond that, 503 with ``Retry-After``."""
RETRY_AFTER_S = 2
PALETTE = ["#4aa3ff", "#ffa657", "#3fb950", "#f778ba", "#e3b341", "#a371f7",
           "#56d4dd", "#ff7b72", "#b5e853", "#d2a8ff", "#2ec4a6", "#c9b18a"]
"""The dashboard's palette (app.js): a drone has one colour on the page and in the PNG."""


def color(drone: str) -> str:
    """app.js ``colorIndex`` for ids ending in a number (uav1 -> slot 0); others hashed."""
    digits = len(drone) - len(drone.rstrip("0123456789"))
    if digits:
        return PALETTE[(int(drone[-digits:][-6:]) + len(PALETTE) - 1) % len(PALETTE)]
    h = 0x811C9DC5
    for ch in drone:
        h = ((h ^ ord(ch)) * 0x01000193) & 0xFFFFFFFF
    return PALETTE[h % len(PALETTE)]


def mission_runs(db: sqlite3.Connection, mission: str) -> list[tuple[float, float | None]]:
    """The mission's runs, sorted and merged: every start to its end (or open), as its log
    marks them (a station restart closes and reopens the same run; an end and a new start
    make two). A database without the bounds table's rows (older version) has one: its row's
    latest start to its end."""
    try:
        bounds = db.execute("SELECT t_start, t_end, kind FROM mission_bounds "
                            "WHERE mission = ? ORDER BY rowid", (mission,)).fetchall()
    except sqlite3.OperationalError:  # a database of an older version, opened read-only
        bounds = []
    if bounds:
        spans = _spans(bounds)
    else:
        row = db.execute("SELECT t_start, t_end FROM missions WHERE name = ?",
                         (mission,)).fetchone()
        spans = [(row[0], row[1] if row[1] is not None and row[1] >= row[0] else None)
                 ] if row and row[0] is not None else []
    runs: list[tuple[float, float | None]] = []
    for a, b in sorted(spans, key=lambda r: r[0]):
        if runs and (runs[-1][1] is None or a <= runs[-1][1]):
            end = runs[-1][1]
            runs[-1] = (runs[-1][0], None if end is None or b is None else max(end, b))
        else:
            runs.append((a, b))
    return runs


def _spans(bounds: list[tuple[float | None, float | None, str]]
           ) -> list[tuple[float, float | None]]:
    """Start-to-end spans of the bounds rows in log order. An operator's start replaces the
    start the station opened the mission with (images before it are not the mission's), but
    an operator's start while an operator's run is open goes on with that run (`make demo`
    starts its mission, then the operator presses start: the first minute is the mission's).
    An end without an open start marks nothing."""
    spans: list[tuple[float, float | None]] = []
    open_start: float | None = None
    open_kind = ""
    for t_start, t_end, kind in bounds:
        if t_start is not None:
            if open_start is None or (open_kind == "open" and kind == "start"):
                open_start, open_kind = t_start, kind
        elif t_end is not None and open_start is not None:
            spans.append((open_start, t_end))
            open_start = None
    if open_start is not None:
        spans.append((open_start, None))
    return spans


def utility_series(db: sqlite3.Connection, mission: str, *, bin_s: float = BIN_S,
                   now: float | None = None) -> dict[str, Any]:
    """Per drone, the utility received per ``bin_s`` over every run of the mission (from its
    first start; before, only the latest start counted: an ``end`` and a new ``start`` left
    5 of 81 stored images in the report), and what it covers: the runs, the images counted
    and those stored outside every run (before the first start, between runs). Without a
    start, from the first image. At most :data:`MAX_BINS` bins: longer missions get wider
    ones.

    While the mission runs (no end recorded) and ``now`` is given, only the bins that are
    over by ``now`` (at least the first): the bin still filling would draw every drone
    dropping towards 0 at the right edge of a live report, a fall that is only the clock."""
    rows = db.execute("SELECT sender, t_rcv, utility FROM images WHERE mission = ? "
                      "AND type = 'image' ORDER BY t_rcv", (mission,)).fetchall()
    runs = mission_runs(db, mission)
    if runs:
        rows_in = [r for r in rows if any(a <= r[1] and (b is None or r[1] <= b)
                                          for a, b in runs)]
    else:
        rows_in = rows
    t0 = runs[0][0] if runs else (rows[0][1] if rows else 0.0)
    t_last = max((r[1] for r in rows_in), default=t0)
    if rows_in and (t_last - t0) // bin_s >= MAX_BINS:  # a long span: wider bins, not more
        bin_s *= math.ceil((t_last - t0) / bin_s / MAX_BINS * (1 + 1e-9))
    n = max(1, int((t_last - t0) // bin_s) + 1) if rows_in else 0
    running = not runs or runs[-1][1] is None
    if now is not None and running:
        n = min(n, max(1, int((now - t0) // bin_s)))
    drones: dict[str, list[float]] = {}
    for sender, t_rcv, utility in rows_in:
        i = int((t_rcv - t0) // bin_s)
        if 0 <= i < n:
            drones.setdefault(str(sender), [0.0] * n)[i] += float(utility)
    return {"mission": mission, "t_start": t0, "bin_s": bin_s,
            "runs": [[a, b] for a, b in runs], "images": len(rows_in),
            "images_outside": len(rows) - len(rows_in),
            "t": [i * bin_s for i in range(n)],
            "drones": {d: {"utility": v, "total": sum(v), "total_text": total_text(sum(v)),
                           "color": color(d)}
                       for d, v in sorted(drones.items())}}


def total_text(total: float) -> str:
    """A drone's total as both charts' legends print it. Each rounded on its own, the page
    (JavaScript, half up) said "total 1" and the picture (Python, half to even) "total 0" for
    one image of U 0.5, and early in a mission every total read 0 or 1."""
    return f"{total:.1f}" if abs(total) < 100 else f"{total:.0f}"


def _gaps(series: dict[str, Any]) -> list[tuple[float, float]]:
    """Between two runs (an end, then a new start), in seconds of the report's axis."""
    runs, t0 = series.get("runs", []), series["t_start"]
    return [(end - t0, start - t0) for (_, end), (start, _) in itertools.pairwise(runs)
            if end is not None]


def figure(series: dict[str, Any]) -> Any:
    """The report's matplotlib ``Figure`` (OO API, a canvas of its own, no pyplot). The legend
    sits right of the plot: inside, it hid the red drone's peak in `make demo`'s report."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8, 3.6), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    for drone, d in series["drones"].items():
        ax.plot(series["t"], d["utility"], color=d["color"], lw=1.8, marker="o", ms=3,
                label=f"{drone} (total {d.get('total_text') or total_text(d['total'])})")
    for gap_start, gap_end in _gaps(series):
        ax.axvspan(gap_start, gap_end, color="#8b949e", alpha=0.2, lw=0)
    # As the page's chart: time from 0, one bin wide at least (one bin was centred on a
    # -0.04..0.04 axis), utility from 0.
    ax.set_xlim(0.0, max([series["bin_s"], *series["t"]]))
    ax.set_ylim(bottom=0.0)
    ax.set_xlabel("mission time (s)")
    ax.set_ylabel(f"utility received per {series['bin_s']:g} s")
    name = "".join(c if c.isprintable() else "?" for c in str(series["mission"]))[:80]
    ax.set_title(f"mission {name}: utility over time per drone")
    ax.grid(alpha=0.3)
    if series["drones"]:
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    fig.tight_layout()
    return fig


def render_png(series: dict[str, Any], path: Path | None) -> bytes:
    """Draw the series (no pyplot, no display: safe on any thread); also written atomically
    to ``path`` unless None."""
    fig = figure(series)
    out = io.BytesIO()
    fig.savefig(out, format="png")
    body = out.getvalue()
    if path is not None:
        replace_file(path, body)
    return body


def replace_file(path: Path, body: bytes) -> None:
    """Write ``body`` under a temp name of this thread's own, then rename it over ``path``:
    a reader (or a second writer) sees the old file or the new one, never a mix."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        with os.fdopen(fd, "wb") as f:
            f.write(body)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def write_png(db_path: Path, mission: str, path: Path) -> Path | None:
    """The report PNG of a finished run from the station's database (None: no database)."""
    if not db_path.exists():
        return None
    con = sqlite3.connect(f"file:{db_path}?mode=ro", uri=True, timeout=10.0)
    try:
        series = utility_series(con, mission)
    finally:
        con.close()
    render_png(series, path)
    return path


T = TypeVar("T")


class RenderGate:
    """At most ``renders`` drawings at once on a pool of their own, ``waiting`` more queued;
    :meth:`run` refuses beyond that (503). A slot is freed when the drawing really ends, not
    when its request goes away, so disconnecting clients cannot pile up work."""

    def __init__(self, renders: int = RENDERS, waiting: int = WAITING) -> None:
        self.pool = ThreadPoolExecutor(renders, thread_name_prefix="gs-report")
        self.room = renders + waiting

    def admit(self) -> None:
        """Raise the 503 now if there is no room (before any work for the request)."""
        if self.room <= 0:
            raise web.HTTPServiceUnavailable(
                text="busy drawing reports: try again shortly",
                headers={"Retry-After": str(RETRY_AFTER_S), "Cache-Control": "no-store"})

    async def run(self, fn: Callable[[], T]) -> T:
        self.admit()
        loop = asyncio.get_running_loop()
        job = self.pool.submit(fn)
        self.room -= 1

        def free(_: Future[T]) -> None:
            with contextlib.suppress(RuntimeError):  # the loop closed first: nothing to free
                loop.call_soon_threadsafe(self._free)

        job.add_done_callback(free)
        return await asyncio.wrap_future(job)

    def _free(self) -> None:
        self.room += 1

    def close(self) -> None:
        self.pool.shutdown(wait=False, cancel_futures=True)


def add_report_routes(app: web.Application, *, static_dir: Path) -> None:
    """``/report``, ``/api/report`` and ``/api/report.png`` (reads: the token middleware
    guards the ``/api/`` ones like every data read)."""
    from ground_station.keys import CONFIG, STORAGE

    async def page(request: web.Request) -> web.StreamResponse:
        return web.FileResponse(static_dir / "report.html",
                                headers={"Cache-Control": "no-cache"})

    async def series_of(request: web.Request) -> dict[str, Any]:
        mission = request.query.get("mission", request.app[CONFIG].mission)
        now = time.time()  # the fleet clock is wall time
        return await request.app[STORAGE].read(
            lambda s: utility_series(s.db, mission, now=now))

    async def api(request: web.Request) -> web.Response:
        return web.json_response(await series_of(request))

    gate = RenderGate()

    async def png(request: web.Request) -> web.Response:
        gate.admit()
        series = await series_of(request)
        config = request.app[CONFIG]
        # A GET writes nothing for a mission the station never heard of: any query string
        # would otherwise create a folder and a file (disk filling by reads, path tricks).
        path = (Path(config.data_dir) / "missions" / safe_name(series["mission"])
                / "utility.png") if series["drones"] else None
        body = await gate.run(lambda: render_png(series, path))
        return web.Response(body=body, content_type="image/png",
                            headers={"Cache-Control": "no-store"})

    async def close_gate(app: web.Application) -> None:
        gate.close()

    app.on_cleanup.append(close_gate)

    app.router.add_get("/report", page)
    app.router.add_get("/api/report", api)
    app.router.add_get("/api/report.png", png)
