"""What the operator sees is true (issue 17), end to end with real processes.

* The built-in vehicle (``uav-sitl vehicle``) changes mode and arms mid-run, driven by a
  pymavlink client like a ground control station; the companion streams images that
  saturate its link under the shipped ``image_streaming`` spec; the ground station's API
  shows the new mode and the armed state within 2 s of the vehicle's HEARTBEAT saying so.
* A vehicle that starts without a fix (0/0, an EKF without origin, like ArduPilot after
  boot) and then loses its autopilot link: no image is stored at 0/0, images taken before
  the fix say "no position", images taken during the outage are stale, and ``export``
  leaves both out of geotags.csv.

Companion and ground station run as their console scripts with default (INFO) logging.
"""

from __future__ import annotations

import asyncio
import contextlib
import csv
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import aiohttp
import cv2
import numpy as np
import pytest

os.environ.setdefault("MAVLINK20", "1")

ROOT = Path(__file__).resolve().parents[2]
KEY = "truth-e2e-fleet-key-0123456789"
FLEET = 9

sys.path.insert(0, str(ROOT / "tests" / "companion"))
from companion_fake_vehicle import FakeVehicle  # noqa: E402

from tests.companion_process import console_script  # noqa: E402
from tests.keys import write_test_keys  # noqa: E402


def _free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _frames(folder: Path, n: int = 8, *, noisy: bool = True) -> Path:
    """640x480 frames; noisy ones are ~170 kB each, so 5 per second saturate the link."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(7)
    for i in range(n):
        image = rng.integers(0, 255, (480, 640, 3), dtype=np.uint8)
        if not noisy:
            image = cv2.GaussianBlur(image, (31, 31), 0)
        cv2.circle(image, (200 + 20 * i, 240), 80, (10, 10, 220), -1)
        cv2.imwrite(str(folder / f"{i:03d}.jpg"), image)
    return folder


class Station:
    """``uav-ground-station run`` as a process, read through its HTTP API."""

    def __init__(self, tmp: Path) -> None:
        self.udp_port = _free_port(socket.SOCK_DGRAM)
        self.http_port = _free_port(socket.SOCK_STREAM)
        self.config = tmp / "gs.toml"
        # no built-in key: the station signs commands with the test key, drones verify them
        self.keys = write_test_keys(tmp / "keys", fleet_key=KEY.encode())
        self.config.write_text(
            "[ground_station]\n"
            f'fleet_key = "{KEY}"\nfleet_id = {FLEET}\ndata_dir = "{tmp / "gs-data"}"\n'
            f'command_key_file = "{self.keys / "command.key"}"\n'
            f'mission = "truth"\nudp_host = "127.0.0.1"\nudp_port = {self.udp_port}\n'
            f"http_port = {self.http_port}\npublic_read = true\nfsync = false\n")
        self.log = tmp / "gs.log"  # a file, not a pipe nobody reads while it runs
        with open(self.log, "w") as log:
            self.proc = subprocess.Popen([console_script("uav-ground-station"), "run", "--config",
                                          str(self.config)], stdout=subprocess.DEVNULL,
                                         stderr=log, text=True)
        self.url = f"http://127.0.0.1:{self.http_port}"

    async def get(self, path: str) -> Any:
        async with aiohttp.ClientSession() as session, session.get(self.url + path) as resp:
            assert resp.status == 200, await resp.text()
            return await resp.json()

    async def ready(self) -> None:
        async with asyncio.timeout(20):
            while True:
                with contextlib.suppress(aiohttp.ClientError, AssertionError):
                    await self.get("/api/stats")
                    return
                assert self.proc.poll() is None, self.log.read_text()[-3000:]
                await asyncio.sleep(0.1)

    async def drone(self, name: str) -> dict[str, Any] | None:
        fleet = await self.get("/api/fleet")
        return next((d for d in fleet["drones"] if d["drone"] == name), None)

    def stop(self) -> str:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        try:
            self.proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        return self.log.read_text()


def _companion(tmp: Path, *, drone: str, mavlink_url: str, station: Station, frames: Path,
               limit_bytes_per_s: float, rate_hz: float = 5.0) -> subprocess.Popen[str]:
    config = tmp / f"{drone}.toml"
    config.write_text(f"""
[drone]
id = "{drone}"
[mavlink]
url = "{mavlink_url}"
heartbeat_timeout_s = 1.5
reconnect_delay_s = 0.2
[camera]
source = "{frames}"
rate_hz = {rate_hz}
jpeg_quality = 80
[mission]
spec = "builtin:image_streaming"
log = "{tmp / (drone + '.jsonl')}"
[ground_station]
host = "127.0.0.1"
port = {station.udp_port}
fleet_id = {FLEET}
fleet_key = "{KEY}"
command_public_key_file = "{station.keys / "command.pub"}"
listen_host = "127.0.0.1"
[constraint]
name = "constant"
params = {{ limit_bytes_per_s = {limit_bytes_per_s} }}
""")
    with open(tmp / f"{drone}.log", "w") as log:
        return subprocess.Popen([console_script("uav-companion"), "run", "--config", str(config)],
                                stdout=subprocess.DEVNULL, stderr=log, text=True,
                                env={**os.environ, "PYTHONUNBUFFERED": "1"})


def _log_of(proc: subprocess.Popen[str]) -> str:
    config = Path(proc.args[-1])  # type: ignore[index]
    log = config.with_suffix(".log")
    return log.read_text() if log.exists() else ""


def _stop(proc: subprocess.Popen[str]) -> tuple[int, str]:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout=20)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        return -9, _log_of(proc)
    return proc.returncode, _log_of(proc)


async def _until(predicate: Any, timeout_s: float, what: str,
                 procs: list[subprocess.Popen[str]]) -> Any:
    deadline = time.monotonic() + timeout_s
    while True:
        value = await predicate()
        if value:
            return value
        for p in procs:
            assert p.poll() is None, f"{p.args[0]} exited"
        if time.monotonic() > deadline:
            pytest.fail(f"not within {timeout_s} s: {what}")
        await asyncio.sleep(0.05)


class Gcs:
    """A pymavlink client of the built-in vehicle: heartbeats, SET_MODE, arm; it records
    when the vehicle's HEARTBEAT first reports each (mode, armed)."""

    def __init__(self, port: int) -> None:
        from pymavlink import mavutil

        self.conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=245)
        self.seen: dict[tuple[str, bool], float] = {}
        self.mode_ids: dict[str, int] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        from pymavlink import mavutil

        next_hb = 0.0
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_hb:
                self.conn.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS,
                                             mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                next_hb = now + 0.5
            msg = self.conn.recv_match(type="HEARTBEAT", blocking=True, timeout=0.1)
            if msg is None or msg.get_srcSystem() == 245:
                continue
            self.mode_ids = self.conn.mode_mapping() or self.mode_ids
            armed = bool(msg.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
            self.seen.setdefault((mavutil.mode_string_v10(msg), armed), time.time())

    def set_mode(self, mode: str) -> None:
        from pymavlink import mavutil

        self.conn.mav.set_mode_send(self.conn.target_system,
                                    mavutil.mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                                    self.mode_ids[mode])

    def arm(self) -> None:
        from pymavlink import mavutil

        self.conn.mav.command_long_send(self.conn.target_system, self.conn.target_component,
                                        mavutil.mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0,
                                        1, 0, 0, 0, 0, 0, 0)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self.conn.close()


@pytest.fixture
def vehicle() -> Iterator[int]:
    # a fix at boot: this test is about mode and arming, not the wait for a GPS fix
    proc = subprocess.Popen([console_script("uav-sitl"), "vehicle", "--port", "0", "--flavour",
                             "ardupilot", "--first-fix", "0"], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True)
    try:
        assert proc.stdout is not None
        ready = json.loads(proc.stdout.readline().removeprefix("READY "))
        yield int(ready["port"])
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()


def _decisions(log: Path, type_name: str) -> list[dict[str, Any]]:
    if not log.exists():
        return []
    return [r for line in log.read_text().splitlines()
            if (r := json.loads(line)).get("type") == type_name and "decision" in r]


@pytest.mark.timeout(150)
async def test_mode_and_arming_reach_the_ground_station_within_2_s_on_a_saturated_link(
        tmp_path: Path, vehicle: int) -> None:
    station = Station(tmp_path)
    gcs = Gcs(vehicle)
    companion = None
    try:
        await station.ready()
        companion = _companion(tmp_path, drone="d1", mavlink_url=f"udpout:127.0.0.1:{vehicle}",
                               station=station, frames=_frames(tmp_path / "frames"),
                               limit_bytes_per_s=30_000.0)
        procs = [station.proc, companion]

        async def initial() -> Any:
            d = await station.drone("d1")
            return d if d and d["mode"] and d["armed"] is False and d["images"] >= 3 else None

        first = await _until(initial, 60, "first status and images at the station", procs)
        assert first["mode"] != "GUIDED"
        log = tmp_path / "d1.jsonl"

        async def saturated() -> bool:  # the optimiser drops images: the link is full
            return sum(not r["decision"]["send"] for r in _decisions(log, "image")) >= 5

        await _until(saturated, 30, "images dropped for the constraint", procs)
        async def mode_ids() -> bool:
            return "GUIDED" in gcs.mode_ids
        await _until(mode_ids, 10, "the vehicle's mode table", procs)

        for want_mode, want_armed, act in (("GUIDED", False, lambda: gcs.set_mode("GUIDED")),
                                          ("GUIDED", True, gcs.arm)):
            async def confirmed(want: tuple[str, bool] = (want_mode, want_armed),
                                act: Any = act) -> float | None:
                if want not in gcs.seen:
                    act()  # resent until the vehicle's HEARTBEAT confirms it
                    await asyncio.sleep(0.3)
                return gcs.seen.get(want)

            t_vehicle = await _until(confirmed, 60, f"vehicle in {want_mode}, armed "
                                     f"{want_armed}", procs)

            async def shown(want_mode: str = want_mode, want_armed: bool = want_armed) -> Any:
                d = await station.drone("d1")
                ok = d is not None and d["mode"] == want_mode and d["armed"] is want_armed
                return time.time() if ok else None

            t_shown = await _until(shown, 10, f"the API shows {want_mode}/{want_armed}", procs)
            delay = t_shown - t_vehicle
            print(f"{want_mode} armed={want_armed}: vehicle {t_vehicle:.3f}, API +{delay:.2f} s")
            assert delay < 2.0, f"{want_mode}/{want_armed} shown {delay:.2f} s after the vehicle"
        d = await station.drone("d1")
        assert d is not None and d["ages"]["mode"] < 2.5 and "mode" not in d["stale"]
        dropped = [r for r in _decisions(log, "image") if not r["decision"]["send"]]
        assert dropped, "the link was not saturated"
    finally:
        gcs.close()
        code, err = _stop(companion) if companion is not None else (0, "")
        station.stop()
    assert code == 0, err[-3000:]


@pytest.mark.timeout(150)
async def test_no_fix_gives_no_position_and_an_outage_gives_stale_geotags(
        tmp_path: Path) -> None:
    vehicle = FakeVehicle(fix_after_s=5.0).start()
    station = Station(tmp_path)
    companion = None
    try:
        await station.ready()
        companion = _companion(tmp_path, drone="d2",
                               mavlink_url=f"udpout:127.0.0.1:{vehicle.port}", station=station,
                               frames=_frames(tmp_path / "frames", noisy=False),
                               limit_bytes_per_s=200_000.0, rate_hz=4.0)
        procs = [station.proc, companion]

        async def images() -> list[dict[str, Any]]:
            return (await station.get("/api/images?mission=truth&order=time&limit=1000")
                    )["images"]

        async def no_position_shown() -> Any:
            d = await station.drone("d2")
            return d if d and d["no_position"] and d["images"] >= 2 else None

        d = await _until(no_position_shown, 40, "the tile says no position", procs)
        assert d["lat_deg"] is None

        async def placed() -> bool:
            return any(i["pose"] == "ok" for i in await images())

        await _until(placed, 30, "images geotagged after the fix", procs)
        vehicle.outage(4.0)  # the autopilot goes quiet; the camera goes on

        async def stale() -> bool:
            return sum(i["pose"] == "stale" for i in await images()) >= 3

        await _until(stale, 30, "images taken during the outage marked stale", procs)

        async def back() -> bool:
            rows = await images()
            t_stale = max(i["t_gen"] for i in rows if i["pose"] == "stale")
            return any(i["pose"] == "ok" and i["t_gen"] > t_stale for i in rows)

        await _until(back, 30, "fresh geotags after the outage", procs)
        d = await station.drone("d2")
        assert d is not None and d["no_position"] is False and d["lat_deg"] == pytest.approx(
            50.0615, abs=1e-3)
    finally:
        code, err = _stop(companion) if companion is not None else (0, "")
        station.stop()
        vehicle.stop()
    assert code == 0, err[-3000:]
    rows = (await asyncio.to_thread(_db_images, tmp_path / "gs-data"))
    poses = {p for *_, p in rows}
    assert poses == {"none", "ok", "stale"}, rows
    assert not [r for r in rows if r[0] is not None and abs(r[0]) < 1e-6], "0/0 stored"
    assert all(lat is None for lat, _, _, p in rows if p == "none")
    assert all(age > 1.0 for _, _, age, p in rows if p == "stale")
    out = tmp_path / "export"
    result = subprocess.run([console_script("uav-ground-station"), "export", "truth", "--out",
                             str(out), "--config", str(station.config)],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    with open(out / "geotags.csv", newline="") as handle:
        exported = list(csv.DictReader(handle))
    ok = sum(p == "ok" for *_, p in rows)
    assert len(exported) == ok and {r["pose"] for r in exported} == {"ok"}
    assert all(float(r["pose_age_s"]) <= 1.0 for r in exported)
    assert f"{len(rows) - ok} images with a stale or no position left out" in result.stderr


def _db_images(data_dir: Path) -> list[tuple[Any, ...]]:
    import sqlite3

    db = sqlite3.connect(data_dir / "ground_station.sqlite3")
    try:
        return list(db.execute("SELECT lat_deg, lon_deg, pose_age_s, pose FROM images"
                               " WHERE path IS NOT NULL"))
    finally:
        db.close()
