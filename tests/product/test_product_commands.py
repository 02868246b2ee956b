"""Product tier: the shipped console scripts, run the way a user runs them (issue 11).

One simulated-vehicle process (``uav-sitl vehicle``, two vehicles), two ``uav-companion run``
processes built from ``examples/companion.toml`` and one ``uav-ground-station run``, all
with their default (INFO) logging, talking over real sockets. The tests drive them through
the HTTP API, the ``uav-ground-station shell`` and MAVLink, and assert effects: what the
drones did, what the station stored, what the optimiser decided. Only ports, ids, file
locations, the keys (made with ``uav-ground-station keygen`` as a user makes them) and the
camera's size/rate (CPU on a 2-core CI machine) differ from the shipped configuration. The
processes are shared by the module's tests, which run in file order (the last one ends the
mission).
"""

from __future__ import annotations

import json
import os
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
DRONES = ("drone1", "drone2")
STARTUP_S = 120.0  # companions warm up the optimiser (numba) before they stream


@dataclass
class Product:
    run_dir: Path
    base_url: str
    token: str
    gs_config: Path
    vehicle_ports: list[int]
    logs: dict[str, Path]
    procs: dict[str, subprocess.Popen[bytes]] = field(default_factory=dict)

    def api(self, method: str, path: str, body: Any = None) -> Any:
        return station_api(self.base_url, self.token, method, path, body)

    def alive(self) -> None:
        for name, proc in self.procs.items():
            if proc.poll() is not None:
                log = self.run_dir / f"{name}.log"
                tail = log.read_text(errors="replace")[-3000:] if log.exists() else ""
                raise AssertionError(f"{name} exited with {proc.returncode}:\n{tail}")

    def until(self, what: str, predicate: Callable[[], Any], timeout_s: float) -> Any:
        deadline = time.monotonic() + timeout_s
        while True:
            self.alive()
            value = predicate()
            if value:
                return value
            if time.monotonic() > deadline:
                raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}")
            time.sleep(0.2)

    def command(self, verb: str, body: dict[str, Any]) -> dict[str, Any]:
        """Issue a command through the API and wait until every drone has its result."""
        issued = self.api("POST", f"/api/mission/{verb}", body)["command"]

        def finished() -> dict[str, Any] | None:
            for command in self.api("GET", "/api/mission")["commands"]:
                if command["command_id"] == issued["command_id"] and command["finished"]:
                    return dict(command)
            return None

        return dict(self.until(f"the results of {verb}", finished, 30.0))

    def images(self) -> list[dict[str, Any]]:
        body = self.api("GET", "/api/images?order=time&limit=1000&mission=product")
        return list(body["images"])


def _companion_config(run_dir: Path, drone: str, mavlink_port: int, gs_port: int,
                      keys: Path) -> Path:
    """``examples/companion.toml`` with this run's ports, id, files and a small camera."""
    text = (ROOT / "examples" / "companion.toml").read_text()
    replacements = {
        'id = "drone1"': f'id = "{drone}"',
        'url = "udpin:127.0.0.1:14550"': f'url = "udpin:127.0.0.1:{mavlink_port}"',
        "width = 640": "width = 320",
        "height = 480": "height = 240",
        "rate_hz = 5.0": "rate_hz = 2.0",
        '# log = "/var/lib/uav-companion/mission.jsonl"':
            f'log = "{run_dir / (drone + ".jsonl")}"',
        "port = 14600": f"port = {gs_port}",
        '# fleet_key_file = "/etc/uav-companion/fleet.key"':
            f'fleet_key_file = "{keys / "fleet.key"}"',
        '# command_public_key_file = "/etc/uav-companion/command.pub"':
            f'command_public_key_file = "{keys / "command.pub"}"',
    }
    for old, new in replacements.items():
        assert text.count(old) == 1, f"examples/companion.toml no longer has {old!r}"
        text = text.replace(old, new)
    path = run_dir / f"{drone}.toml"
    path.write_text(text)
    return path


def _start(product: Product, name: str, argv: list[str]) -> None:
    log = open(product.run_dir / f"{name}.log", "wb")  # noqa: SIM115 - the child owns it
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    product.procs[name] = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT,
                                           stdin=subprocess.DEVNULL, env=env,
                                           start_new_session=True)
    log.close()


def _stop(procs: dict[str, subprocess.Popen[bytes]]) -> None:
    for proc in procs.values():
        if proc.poll() is None:
            proc.terminate()
    for proc in procs.values():
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=5)


@pytest.fixture(scope="module")
def product(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Product]:
    gs_bin, companion_bin, sitl_bin = (console_script(name) for name in (
        "uav-ground-station", "uav-companion", "uav-sitl"))
    run_dir = tmp_path_factory.mktemp("product")
    gs_udp, http_port = free_port(), free_port(kind=socket.SOCK_STREAM)
    gs_config = run_dir / "gs.toml"
    gs_config.write_text(
        "[ground_station]\n"
        f'data_dir = "{run_dir / "gs"}"\nmission = "product"\n'
        f'udp_host = "127.0.0.1"\nudp_port = {gs_udp}\n'
        f'http_host = "127.0.0.1"\nhttp_port = {http_port}\n')
    # the fleet's keys as a user makes them: in data_dir/keys, where `run` finds them
    keygen = subprocess.run([gs_bin, "keygen", "--config", str(gs_config)],
                            capture_output=True, text=True, timeout=60, check=False)
    assert keygen.returncode == 0, keygen.stdout + keygen.stderr
    keys = run_dir / "gs" / "keys"
    assert (keys / "fleet.key").is_file() and (keys / "command.pub").is_file(), keygen.stdout
    mavlink_ports = [free_port() for _ in DRONES]
    product = Product(run_dir=run_dir, base_url=f"http://127.0.0.1:{http_port}", token="",
                      gs_config=gs_config, vehicle_ports=[],
                      logs={d: run_dir / f"{d}.jsonl" for d in DRONES})
    try:
        _start(product, "ground_station", [gs_bin, "run", "--config", str(gs_config)])
        ready = run_dir / "vehicles.json"
        _start(product, "vehicles", [
            sitl_bin, "vehicle", "--count", str(len(DRONES)), "--port", "0",
            "--scene", "demo", "--pattern", "survey", "--speedup", "5",
            *[a for p in mavlink_ports for a in ("--out", f"127.0.0.1:{p}")],
            "--ready-file", str(ready)])
        token_file = run_dir / "gs" / "token"
        product.until("the ground station's token", token_file.exists, 30)
        product.token = token_file.read_text().strip()
        product.until("the ground station's API", lambda: _reachable(product), 30)
        product.until("the vehicles", ready.exists, 30)
        product.vehicle_ports = [int(r["port"]) for r in json.loads(ready.read_text())]
        for drone, port in zip(DRONES, mavlink_ports, strict=True):
            config = _companion_config(run_dir, drone, port, gs_udp, keys)
            _start(product, drone, [companion_bin, "run", "--config", str(config)])
        product.until("both drones' images at the ground station", lambda: {
            i["sender"] for i in product.images()} >= set(DRONES), STARTUP_S)
        yield product
    finally:
        _stop(product.procs)


def _reachable(product: Product) -> bool:
    try:
        product.api("GET", "/api/stats")
    except OSError:
        return False
    return True


def _decisions(path: Path) -> list[dict[str, Any]]:
    records = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    return [r for r in records if "decision" in r and r.get("type") == "image"]


def test_shell_commands_reach_done_on_every_drone(product: Product) -> None:
    """The shell as an operator types it: names a newcomer guesses, results per drone."""
    out = subprocess.run(
        [console_script("uav-ground-station"), "shell", "--config", str(product.gs_config),
         "-c", "drones 2; start; report; status"],
        capture_output=True, text=True, timeout=90, check=False)
    assert out.returncode == 0, out.stderr
    assert "2 drone(s): drone1, drone2" in out.stdout
    assert "start: done 2/2" in out.stdout, out.stdout
    assert "request_report: done 2/2" in out.stdout, out.stdout
    for drone in DRONES:  # the counters each drone sent back
        line = next(x for x in out.stdout.splitlines() if x.startswith(f"  {drone}: done"))
        assert "sent=" in line and "generated=" in line
    assert "Traceback" not in out.stdout + out.stderr


def test_set_params_changes_what_the_optimiser_does(product: Product) -> None:
    product.until("a searched image decision (the shipped 300 iterations)", lambda: any(
        r["decision"].get("iterations", 0) > 5
        for p in product.logs.values() for r in _decisions(p)), 60)  # under load: not yet
    before = {d: len(_decisions(p)) for d, p in product.logs.items()}
    command = product.command("params", {"params": "mcts_iterations=5"})
    assert command["summary"]["done"] == 2, command
    t_done = time.time()
    product.until("new image decisions on both drones", lambda: all(
        len(_decisions(p)) >= before[d] + 4 for d, p in product.logs.items()), 60)
    for path in product.logs.values():
        after = [r for r in _decisions(path) if r["t_gen"] > t_done]
        searched = [r["decision"]["iterations"] for r in after if "iterations" in r["decision"]]
        assert searched and max(searched) == 5, searched  # was the shipped 300


def test_a_rejected_parameter_is_an_error_with_the_reason(product: Product) -> None:
    command = product.command("params", {"params": "mcts_iterations=9, warp_speed=2"})
    assert command["summary"] == {"done": 0, "error": 2, "no reply": 0, "waiting": 0,
                                  "total": 2}
    for entry in command["results"].values():
        assert "unknown parameter 'warp_speed'" in entry["reason"]
    # all or nothing: the station shows neither key in effect (before: both were listed
    # under "params requested" like the applied mcts_iterations=5)
    mission = product.api("GET", "/api/mission")
    assert mission["params"] == {"mcts_iterations": 5}
    assert mission["params_rejected"] == {"mcts_iterations": 9, "warp_speed": 2}


def _vehicle_command(port: int, command: int, param1: float) -> int:
    """A COMMAND_LONG to the vehicle on ``port`` as a second GCS would send it (system 250):
    the COMMAND_ACK's result."""
    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink import mavutil

    link = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=250)
    try:
        link.mav.heartbeat_send(6, 8, 0, 0, 0)
        assert link.wait_heartbeat(timeout=10) is not None
        link.mav.command_long_send(link.target_system, 1, command, 0, param1, 0, 0, 0, 0, 0, 0)
        ack = link.recv_match(type="COMMAND_ACK", blocking=True, timeout=10)
        assert ack is not None
        return int(ack.result)
    finally:
        link.close()


def test_a_vehicle_change_shows_at_the_ground_station(product: Product) -> None:
    """Arm vehicle 2 over MAVLink: its companion reports it, the station's tile shows it."""
    def armed() -> dict[str, Any]:
        tiles = product.api("GET", "/api/fleet")["drones"]
        return {t["drone"]: t.get("armed") for t in tiles}

    assert armed()["drone2"] is False
    assert _vehicle_command(product.vehicle_ports[1], 400, 1) == 0  # arm
    product.until("drone2 armed at the ground station", lambda: armed()["drone2"] is True, 20)
    assert armed()["drone1"] is False


def test_an_autopilot_reboot_shows_no_stale_state(product: Product) -> None:
    """MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN to vehicle 1 (disarmed): ACCEPTED, 4 s of silence, a
    boot from scratch. While the companion does not hear its autopilot the station shows its
    mode, arming and fix as unknown (it showed the last ones, as fresh as any), and after the
    reboot what the new boot says, the fix only once the new boot reports one."""
    # ACCEPTED (the fake answered UNSUPPORTED before)
    assert _vehicle_command(product.vehicle_ports[0], 246, 1) == 0
    seen: list[tuple[Any, ...]] = []

    def back() -> bool:
        tile = next(t for t in product.api("GET", "/api/fleet")["drones"]
                    if t["drone"] == "drone1")
        seen.append((tile["autopilot_connected"], tile["mode"], tile["armed"], tile["gps_fix"]))
        lost = [s for s in seen if s[0] is False]
        return bool(lost) and seen[-1][0] is True and seen[-1][3] == 3

    product.until("drone1's autopilot lost, then back with a fix", back, 45)
    lost = [s for s in seen if s[0] is False]
    assert lost and all(s[1:] == (None, None, None) for s in lost), seen
    after = seen[seen.index(lost[-1]) + 1:]
    assert after[-1][1:] == ("LOITER", False, 3), after  # PX4 boots in Hold


def test_after_end_no_new_image_is_stored(product: Product) -> None:
    command = product.command("end", {})
    assert command["summary"]["done"] == 2, command
    t_done = time.time()
    time.sleep(1.0)  # images sent before the end may still be on their way
    stored = len(product.images())
    time.sleep(3.0)  # 6 frames per drone at 2 Hz
    product.alive()
    late = [i for i in product.images() if i["t_gen"] > t_done]
    assert late == []
    assert len(product.images()) == stored
    # the drones still send status, so an ended mission is not a lost link
    alerts = product.api("GET", "/api/alerts")["alerts"]
    assert not [a for a in alerts if a["t"] > t_done and "link lost" in a["text"]], alerts
    for path in product.logs.values():  # the drones still decide nothing is sent
        records = [json.loads(x) for x in path.read_text().splitlines() if x.strip()]
        sent_late = [r for r in records if r.get("type") == "image" and r.get("t_sent")
                     and r["t_sent"] > t_done]
        assert sent_late == []


def test_no_process_logged_a_traceback(product: Product) -> None:
    product.alive()
    for name in product.procs:
        text = (product.run_dir / f"{name}.log").read_text(errors="replace")
        assert "Traceback" not in text, f"{name}:\n{text[-3000:]}"
