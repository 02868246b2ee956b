"""Operator checks (audit 12), product tier: restarts in the middle of a mission.

The shipped console scripts with their default (INFO) logging: ``uav-ground-station run``,
``uav-sitl vehicle`` and a ``uav-companion run`` built from ``examples/companion.toml`` with
``wait_for_start = true`` (as ``uav-sitl fleet`` writes it). Found by hand first:

* a companion killed (``kill -9``) and restarted mid-mission stayed ``idle`` for the rest of
  the mission (no image), its ``set_params`` lost, while the station showed ``start: done``;
* a station restarted mid-mission (same data dir) showed phase ``idle``: the start, the
  parameters and every acknowledged command's results were gone;
* a companion restarted while the station was down was never told to start either.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

from sitl.fleet_config import free_port
from tests.companion_process import console_script, station_api

ROOT = Path(__file__).resolve().parents[2]


@dataclass
class Fleet:
    run_dir: Path
    gs_config: Path
    companion_config: Path
    base_url: str
    log: Path
    procs: dict[str, subprocess.Popen[bytes]] = field(default_factory=dict)

    def start(self, name: str, argv: list[str]) -> None:
        log = open(self.run_dir / f"{name}.log", "ab")  # noqa: SIM115 - the child owns it
        self.procs[name] = subprocess.Popen(
            argv, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
            env={**os.environ, "PYTHONUNBUFFERED": "1"}, start_new_session=True)
        log.close()

    def start_station(self) -> None:
        self.start("station", [console_script("uav-ground-station"), "run", "--config",
                               str(self.gs_config)])
        self.until("the station's API", lambda: _try(lambda: self.api("GET", "/api/stats")), 30)

    def start_companion(self) -> None:
        self.start("drone1", [console_script("uav-companion"), "run", "--config",
                              str(self.companion_config)])

    def stop(self, name: str, sig: int = signal.SIGINT) -> int:
        proc = self.procs.pop(name)
        proc.send_signal(sig)
        try:
            return proc.wait(timeout=20)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()

    @property
    def token(self) -> str:
        return (self.run_dir / "gs" / "token").read_text().strip()

    def api(self, method: str, path: str, body: Any = None) -> Any:
        return station_api(self.base_url, self.token, method, path, body)

    def until(self, what: str, predicate: Callable[[], Any], timeout_s: float) -> Any:
        deadline = time.monotonic() + timeout_s
        while True:
            for name, proc in self.procs.items():
                if proc.poll() is not None:
                    tail = (self.run_dir / f"{name}.log").read_text(errors="replace")[-3000:]
                    raise AssertionError(f"{name} exited with {proc.returncode}:\n{tail}")
            value = predicate()
            if value:
                return value
            if time.monotonic() > deadline:
                raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}")
            time.sleep(0.2)

    def command(self, verb: str, body: dict[str, Any]) -> dict[str, Any]:
        cid = self.api("POST", f"/api/mission/{verb}", body)["command"]["command_id"]

        def finished() -> dict[str, Any] | None:
            return next((c for c in self.api("GET", "/api/mission")["commands"]
                         if c["command_id"] == cid and c["finished"]), None)
        return dict(self.until(f"the result of {verb}", finished, 30))

    def images_since(self, t: float) -> list[dict[str, Any]]:
        images = self.api("GET", "/api/images?order=time&limit=1000&mission=ops")["images"]
        return [i for i in images if i["t_gen"] > t]

    def decisions_since(self, t: float) -> list[dict[str, Any]]:
        lines = (self.run_dir / "drone1.jsonl").read_text().splitlines()
        records = [json.loads(x) for x in lines if x.strip() and x.endswith("}")]
        return [r for r in records if r.get("type") == "image" and r["t_gen"] > t
                and "iterations" in r.get("decision", {})]


def _try(call: Callable[[], Any]) -> Any:
    try:
        return call()
    except OSError:
        return None


def _companion_config(run_dir: Path, mavlink_port: int, gs_port: int) -> Path:
    text = (ROOT / "examples" / "companion.toml").read_text()
    keys = run_dir / "gs" / "keys"
    for old, new in {
        'url = "udpin:127.0.0.1:14550"': f'url = "udpin:127.0.0.1:{mavlink_port}"',
        "width = 640": "width = 320", "height = 480": "height = 240",
        "rate_hz = 5.0": "rate_hz = 2.0",
        "wait_for_start = false": "wait_for_start = true",
        '# log = "/var/lib/uav-companion/mission.jsonl"': f'log = "{run_dir / "drone1.jsonl"}"',
        "port = 14600": f"port = {gs_port}",
        '# fleet_key_file = "/etc/uav-companion/fleet.key"':
            f'fleet_key_file = "{keys / "fleet.key"}"',
        '# command_public_key_file = "/etc/uav-companion/command.pub"':
            f'command_public_key_file = "{keys / "command.pub"}"',
    }.items():
        assert text.count(old) == 1, f"examples/companion.toml no longer has {old!r}"
        text = text.replace(old, new)
    path = run_dir / "drone1.toml"
    path.write_text(text)
    return path


@pytest.fixture
def fleet(tmp_path: Path) -> Iterator[Fleet]:
    gs_udp, http_port = free_port(), free_port(kind=socket.SOCK_STREAM)
    gs_config = tmp_path / "gs.toml"
    gs_config.write_text(
        f'[ground_station]\ndata_dir = "{tmp_path / "gs"}"\nmission = "ops"\n'
        f'udp_host = "127.0.0.1"\nudp_port = {gs_udp}\n'
        f'http_host = "127.0.0.1"\nhttp_port = {http_port}\n')
    keygen = subprocess.run([console_script("uav-ground-station"), "keygen", "--config",
                             str(gs_config)], capture_output=True, text=True, timeout=60,
                            check=False)
    assert keygen.returncode == 0, keygen.stderr
    mavlink = free_port()
    fleet = Fleet(run_dir=tmp_path, gs_config=gs_config,
                  companion_config=_companion_config(tmp_path, mavlink, gs_udp),
                  base_url=f"http://127.0.0.1:{http_port}", log=tmp_path / "station.log")
    try:
        fleet.start_station()
        fleet.start("vehicle", [console_script("uav-sitl"), "vehicle", "--port", "0", "--scene",
                                "demo", "--first-fix", "0", "--out", f"127.0.0.1:{mavlink}"])
        fleet.start_companion()
        fleet.until("drone1's optimiser ready at the station", lambda: any(
            d["drone"] == "drone1" and d.get("optimiser_ready")
            for d in fleet.api("GET", "/api/fleet")["drones"]), 120)
        yield fleet
    finally:
        for name in list(fleet.procs):
            fleet.stop(name, signal.SIGTERM)


@pytest.mark.slow  # ~40 s on a loaded 2-core machine; the fast tier is
# test_ground_station_mission_restarts.py
def test_restarted_companion_and_station_rejoin_the_running_mission(fleet: Fleet) -> None:
    assert fleet.command("start", {})["summary"]["done"] == 1
    params = fleet.command("params", {"params": "mcts_iterations=7"})
    assert params["summary"]["done"] == 1

    # kill -9 the companion and start it again: it runs the mission, with the parameters
    fleet.until("ten images of the first run", lambda: len(fleet.images_since(0)) >= 10, 60)
    first_run = fleet.images_since(0)
    os.killpg(fleet.procs.pop("drone1").pid, signal.SIGKILL)
    t_restart = time.time()
    fleet.start_companion()
    fleet.until("images of the restarted companion", lambda: fleet.images_since(t_restart), 30)
    # its seqs start from 0 again: once they cover the first run's, the first run's images
    # are all still there (an image was replaced, row and file, by the restarted run's image
    # of the same seq; types share the counter, so which seqs meet varies)
    last_seq = max(i["seq"] for i in first_run)
    fleet.until("restarted images past the first run's seqs", lambda: max(
        [i["seq"] for i in fleet.images_since(t_restart)], default=-1) >= last_seq, 60)
    kept = {(i["seq"], i["t_gen"], i["size"]) for i in fleet.images_since(0)}
    assert {(i["seq"], i["t_gen"], i["size"]) for i in first_run} <= kept
    decided = fleet.until("searched decisions in its mission log",
                          lambda: fleet.decisions_since(t_restart), 20)
    assert {r["decision"]["iterations"] for r in decided} == {7}  # the shipped 300 before
    start_cid = fleet.api("GET", "/api/mission")["commands"][0]["command_id"]

    # Ctrl-C the station and start it again on the same data dir: the mission is there
    assert fleet.stop("station") == 0
    fleet.start_station()
    mission = fleet.api("GET", "/api/mission")
    assert mission["phase"] == "running"
    assert mission["params"] == {"mcts_iterations": 7}
    assert [(c["command_id"], c["name"], c["summary"]["done"]) for c in mission["commands"]] \
        == [(start_cid, "start", 1), (params["command_id"], "set_params", 1)]

    # the companion restarts while the station is down: told to start when both are back
    assert fleet.stop("station") == 0
    os.killpg(fleet.procs.pop("drone1").pid, signal.SIGKILL)
    fleet.start_companion()
    time.sleep(1.0)
    t_restart = time.time()
    fleet.start_station()
    fleet.until("images of the companion restarted while the station was down",
                lambda: fleet.images_since(t_restart), 30)
    log = (fleet.run_dir / "station.log").read_text()
    assert "Traceback" not in log + (fleet.run_dir / "drone1.log").read_text()


def test_the_latest_start_or_end_decides_on_the_drone_and_the_station(fleet: Fleet) -> None:
    """Found driving the shipped station with the API: an end sent while a start was
    scheduled did not stop the start (the fleet streamed after "end mission"); a start
    after a scheduled end was ended by it, while the station said ``running``."""
    def tile() -> dict[str, Any]:
        return next(d for d in fleet.api("GET", "/api/fleet")["drones"] if d["drone"] == "drone1")

    scheduled = fleet.api("POST", "/api/mission/start", {"delay_s": 3})["command"]
    assert fleet.command("end", {})["summary"]["done"] == 1
    t_cancelled = scheduled["t_exec"]
    time.sleep(max(0.0, t_cancelled - time.time()) + 2.0)
    mission = fleet.api("GET", "/api/mission")
    assert mission["phase"] == "idle" and mission["t_start"] is None
    start = next(c for c in mission["commands"] if c["command_id"] == scheduled["command_id"])
    assert start["superseded_by"] is not None and start["finished"]
    assert fleet.images_since(t_cancelled) == []  # the drone skipped the start
    assert tile().get("mission") != "running"

    assert fleet.command("start", {})["summary"]["done"] == 1
    later_end = fleet.api("POST", "/api/mission/end", {"delay_s": 4})["command"]
    assert fleet.command("end", {})["summary"]["done"] == 1
    assert fleet.command("start", {})["summary"]["done"] == 1
    time.sleep(max(0.0, later_end["t_exec"] - time.time()) + 1.0)
    t_after = time.time()
    fleet.until("images after the replaced end's time", lambda: fleet.images_since(t_after), 20)
    assert fleet.api("GET", "/api/mission")["phase"] == "running"
    assert tile().get("mission") == "running"
    assert "Traceback" not in (fleet.run_dir / "drone1.log").read_text()
