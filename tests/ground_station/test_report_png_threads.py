"""``/api/report.png`` drawn off the event loop: no pyplot (its figure manager is global, not
thread-safe), the file replaced atomically, and a bounded number of drawings at once (a real
``uav-ground-station run`` under a burst of requests)."""

from __future__ import annotations

import asyncio
import os
import subprocess
import sys
import threading
from pathlib import Path
from typing import Any

import aiohttp

from ground_station.report_page import RENDERS, WAITING, render_png
from ground_station.storage import Storage
from tests.station_process import running_station

PNG = b"\x89PNG\r\n\x1a\n"


def _series(mission: str, scale: float = 1.0) -> dict[str, Any]:
    return {"mission": mission, "t_start": 0.0, "bin_s": 5.0, "t": [0.0, 5.0, 10.0],
            "drones": {"uav1": {"utility": [3.0 * scale, 0.0, 1.0], "total": 4.0 * scale,
                                "color": "#4aa3ff"},
                       "uav3": {"utility": [0.0, 11.0, 0.5 * scale], "total": 11.5,
                                "color": "#3fb950"}}}


def test_drawing_does_not_use_pyplot() -> None:
    """pyplot keeps one process-wide figure manager: drawn from pool threads it can mix
    figures. A fresh interpreter shows whether the renderer touches it at all."""
    code = ("import sys\nfrom ground_station.report_page import render_png\n"
            f"body = render_png({_series('m')!r}, None)\n"
            "assert body[:8] == b'\\x89PNG\\r\\n\\x1a\\n'\n"
            "print('pyplot' if 'matplotlib.pyplot' in sys.modules else 'no pyplot')\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, check=False)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "no pyplot"


def test_the_png_file_is_replaced_never_rewritten_in_place(tmp_path: Path) -> None:
    """A second name for the old file still holds the old bytes: the new PNG went to a new
    inode renamed over the path (a reader mid-way never sees half of each)."""
    path = tmp_path / "missions" / "m" / "utility.png"
    path.parent.mkdir(parents=True)
    path.write_bytes(b"old png")
    os.link(path, tmp_path / "reader-has-it-open")
    body = render_png(_series("m"), path)
    assert (tmp_path / "reader-has-it-open").read_bytes() == b"old png"
    assert path.read_bytes() == body and body[:8] == PNG
    assert sorted(p.name for p in path.parent.iterdir()) == ["utility.png"]  # no temp left


def test_concurrent_renders_draw_what_one_render_draws(tmp_path: Path) -> None:
    """Six threads draw six different series into one file at once: each gets exactly the
    bytes a render alone gives, and the file is one of them, whole."""
    series = [_series(f"m{i}", scale=1.0 + i) for i in range(6)]
    alone = [render_png(s, None) for s in series]
    path = tmp_path / "utility.png"
    bodies: list[bytes | None] = [None] * len(series)
    start = threading.Barrier(len(series))

    def draw(i: int) -> None:
        start.wait()
        bodies[i] = render_png(series[i], path)

    threads = [threading.Thread(target=draw, args=(i,)) for i in range(len(series))]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert bodies == alone
    assert path.read_bytes() in alone
    assert [p.name for p in tmp_path.iterdir()] == ["utility.png"]


def _fill(data: Path, mission: str) -> None:
    storage = Storage(data, fsync=False)
    storage.db.execute("INSERT INTO missions (name, t_created, t_start) VALUES (?, 0, 100.0)",
                       (mission,))
    for seq, (sender, t, u) in enumerate([("uav1", 101.0, 1.0), ("uav3", 106.0, 11.0),
                                          ("uav1", 112.0, 1.0)]):
        storage.db.execute("INSERT INTO images (mission, sender, seq, type, t_gen, t_rcv, "
                           "size, utility) VALUES (?, ?, ?, 'image', ?, ?, 100, ?)",
                           (mission, sender, seq, t - 0.1, t, u))
    storage.db.close()


async def _burst(port: int, token: str, n: int) -> list[tuple[int, str | None, bytes]]:
    url = f"http://127.0.0.1:{port}/api/report.png?mission=demo"
    headers = {"Authorization": f"Bearer {token}"}
    connector = aiohttp.TCPConnector(limit=0, force_close=True)
    async with aiohttp.ClientSession(connector=connector) as session:
        async def one() -> tuple[int, str | None, bytes]:
            async with session.get(url, headers=headers) as r:
                return r.status, r.headers.get("Retry-After"), await r.read()

        return await asyncio.gather(*(one() for _ in range(n)))


def test_a_burst_of_png_requests_is_bounded_and_nothing_is_torn(tmp_path: Path) -> None:
    """16 requests at once: RENDERS draw, WAITING wait, the rest get 503 + Retry-After at
    once (the old code drew all 16 on the shared default pool). Every PNG served is whole and
    the same; so is the file; once the burst is over a request is served again."""
    _fill(tmp_path / "data", "demo")
    with running_station(tmp_path) as station:
        replies = asyncio.run(_burst(station.port, station.token, 16))
        ok = [body for status, _, body in replies if status == 200]
        busy = [(status, retry) for status, retry, _ in replies if status != 200]
        assert len(ok) >= RENDERS + WAITING  # the first ones in are all served
        assert busy and set(busy) == {(503, "2")}, busy
        assert ok[0][:8] == PNG and set(ok) == {ok[0]}
        png = tmp_path / "data" / "missions" / "demo" / "utility.png"
        assert png.read_bytes() == ok[0]
        (again,) = asyncio.run(_burst(station.port, station.token, 1))
        assert again[0] == 200 and again[2] == ok[0]
        assert "Traceback" not in station.log_text()
    assert sorted(p.name for p in png.parent.iterdir() if "utility" in p.name) == \
        ["utility.png"]
