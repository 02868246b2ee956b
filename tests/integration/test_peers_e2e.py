"""Peer sharing end to end, as processes: two `uav-companion run` on the shared medium
(loopback broadcast), each with its own `uav-sitl vehicle` (ArduPilot, ADSB_TYPE=1).

A spec sends ``position`` to ``["ground", "peers"]``; each companion hears the other's
positions, shows them at ``GET /peers`` with their age, and injects them as ADSB_VEHICLE: each
vehicle's traffic list (streamed back to a listening GCS socket) holds the other drone, and a
ground-side listener on the medium hears both drones' positions.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import os
import re
import secrets
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.peers import callsign_for
from companion.protocol import Decoder, MessageReassembled, ReportReceived
from companion.transport import open_medium_socket, parse_medium
from tests.companion_process import ground_station_toml

BIN = Path(sys.executable).parent
KEY = f"peers-e2e-{secrets.token_hex(12)}".encode()
"""Per run: a concurrent run of this test (another checkout, same medium port by chance)
is not taken for a peer."""
FLEET = 11
SPEC = Path(__file__).resolve().parents[2] / "utility_specs" / "missions" / "telemetry.toml"


def free_port(kind: int = socket.SOCK_DGRAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def spec_with_peer_positions(path: Path) -> Path:
    text = SPEC.read_text()
    assert "[types.position]" in text
    path.write_text(text.replace("[types.position]",
                                 '[types.position]\nreceivers = ["ground", "peers"]', 1))
    return path


def companion_config(path: Path, *, drone: str, vehicle_port: int, gs_port: int, medium: str,
                     spec: Path) -> Path:
    path.write_text(f"""
[drone]
id = "{drone}"
[mavlink]
url = "udpout:127.0.0.1:{vehicle_port}"
[camera]
enabled = false
[mission]
spec = "{spec}"
log = "{path.parent / (drone + '.jsonl')}"
{ground_station_toml(gs_port, fleet_id=FLEET, fleet_key=KEY)}
[budgets]
mcts_iterations = 50
[telemetry]
position_rate_hz = 2.0
[constraint]
name = "constant"
params = {{ limit_bytes_per_s = 100000.0 }}
[peers]
medium = "{medium}"
adsb_rate_hz = 2.0
http = "127.0.0.1:0"
""")
    return path


async def get_json(port: int, path: str) -> Any:
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(f"GET {path} HTTP/1.0\r\n\r\n".encode())
    raw = await reader.read()
    writer.close()
    return json.loads(raw.partition(b"\r\n\r\n")[2])


@pytest.mark.slow  # two companions warm up their optimisers: 30-100 s on a busy 2-core box
@pytest.mark.timeout(300)
async def test_two_drones_know_each_other_in_companion_and_autopilot(tmp_path: Path) -> None:
    medium_text = f"broadcast:127.255.255.255:{free_port()}"
    medium = parse_medium(medium_text)
    ground_medium = open_medium_socket(medium)
    gs_unicast = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # statuses land here
    gs_unicast.bind(("127.0.0.1", 0))
    spec = spec_with_peer_positions(tmp_path / "spec.toml")
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "MAVLINK20": "1"}
    vehicles = subprocess.Popen(
        [str(BIN / "uav-sitl"), "vehicle", "--port", "0", "--count", "2", "--flavour",
         "ardupilot", "--first-fix", "0", "--param", "ADSB_TYPE=1"],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env)
    procs: list[subprocess.Popen[str]] = []
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs.setblocking(False)
    try:
        assert vehicles.stdout is not None
        ports = [json.loads(vehicles.stdout.readline().removeprefix("READY "))["port"]
                 for _ in range(2)]
        for i, drone in enumerate(("drone1", "drone2")):
            config = companion_config(tmp_path / f"{drone}.toml", drone=drone,
                                      vehicle_port=ports[i],
                                      gs_port=gs_unicast.getsockname()[1], medium=medium_text,
                                      spec=spec)
            procs.append(subprocess.Popen(  # stderr to a file: a full pipe would block it
                [str(BIN / "uav-companion"), "run", "--config", str(config)],
                stdout=subprocess.DEVNULL, stderr=(tmp_path / f"{drone}.err").open("w"),
                text=True, env=env))
        decoder = Decoder(FLEET, KEY, local_id="gs")
        ground_heard: set[str] = set()
        traffic: dict[int, set[str]] = {0: set(), 1: set()}
        tx = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
        parsers = [mavlink.MAVLink(None), mavlink.MAVLink(None)]
        peers_seen: dict[str, Any] = {}
        reported: dict[str, set[str]] = {"drone1": set(), "drone2": set()}
        """Per reporting drone: whose messages its receiver reports on the medium list."""
        t0 = time.monotonic()

        def state() -> str:
            return (f"traffic lists {traffic}, ground heard {sorted(ground_heard)}, "
                    f"/peers {peers_seen}, peers' reports {reported}")

        deadline = time.monotonic() + 200  # a safety net: the loop ends on the effects
        http: list[int | None] = [None, None]
        while True:
            assert time.monotonic() < deadline, "after 200 s: " + state() + logs(tmp_path)
            for proc in procs:
                assert proc.poll() is None, logs(tmp_path)
            for port in ports:  # a GCS on each vehicle: its ADSB stream
                gcs.sendto(mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3).pack(tx),
                           ("127.0.0.1", port))
            # Everything both vehicles streamed since the last round, not one datagram a
            # round: they stream dozens a second, and reading one per round let the socket
            # overflow, so one vehicle's ADSB_VEHICLE could go unseen for 200 s.
            while True:
                try:
                    data, addr = gcs.recvfrom(4096)
                except BlockingIOError:
                    break
                if addr[1] in ports:
                    i = ports.index(addr[1])
                    for m in parsers[i].parse_buffer(data) or []:
                        if m.get_type() == "ADSB_VEHICLE":
                            traffic[i].add(m.callsign)
            while True:
                try:
                    data, addr = ground_medium.recvfrom(2048)
                except BlockingIOError:
                    break
                decoder.receive_datagram(data, addr, time.time())
                while (ev := decoder.next_event()) is not None:
                    if isinstance(ev, MessageReassembled):
                        ground_heard.add(f"{ev.message.sender}/{ev.message.type}")
                    elif isinstance(ev, ReportReceived) and ev.reporter in reported:
                        reported[ev.reporter] |= {e.sender for e in ev.report.entries
                                                  if e.type == "position"}
            for i, drone in enumerate(("drone1", "drone2")):
                http[i] = http[i] or http_port(tmp_path / f"{drone}.err")
                if http[i] is not None:  # the port it bound (0 asked: no port to steal)
                    with contextlib.suppress(OSError):
                        peers_seen[drone] = await get_json(http[i], "/peers")
            if (traffic[0] >= {callsign_for("drone2")}
                    and traffic[1] >= {callsign_for("drone1")}
                    and {"drone1/position", "drone2/position"} <= ground_heard
                    and all(len(p.get("peers", [])) == 1 for p in peers_seen.values())
                    and len(peers_seen) == 2
                    and all(positions_fresh(p) for p in peers_seen.values())
                    and reported == {"drone1": {"drone2"}, "drone2": {"drone1"}}):
                break
            await asyncio.sleep(0.1)
        elapsed = time.monotonic() - t0
        for me, other in (("drone1", "drone2"), ("drone2", "drone1")):
            [peer] = peers_seen[me]["peers"]
            assert peer["drone"] == other
            assert peer["position"]["age_s"] < 2.5  # 2 Hz positions, loopback
        # a drone's own callsign is never in its own autopilot's list
        assert callsign_for("drone1") not in traffic[0]
        assert callsign_for("drone2") not in traffic[1]
        print(f"peers known in companions, autopilots and the ground after {elapsed:.1f} s")
    finally:
        for proc in procs:
            proc.send_signal(signal.SIGINT)
        for proc in procs:
            try:
                proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        vehicles.terminate()
        try:
            vehicles.wait(10)
        except subprocess.TimeoutExpired:
            vehicles.kill()
        gcs.close()
        ground_medium.close()
        gs_unicast.close()
    assert "Traceback" not in logs(tmp_path), logs(tmp_path)
    for drone in ("drone1", "drone2"):  # each reported what it heard from its one peer
        text = (tmp_path / f"{drone}.err").read_text()
        assert re.search(r"peers: [1-9]\d* messages heard from 1 peers, [1-9]\d* receiver "
                         r"reports sent", text), text[-3000:]


def http_port(err: Path) -> int | None:
    """The port a companion's ``/peers`` endpoint bound, from its log line."""
    found = re.search(r"peer state on http://[0-9.]+:(\d+)/peers", err.read_text())
    return int(found.group(1)) if found else None


def positions_fresh(answer: Any) -> bool:
    """Every peer's position in a ``/peers`` answer is younger than 2.5 s (2 Hz, loopback).
    Waited for, not sampled once: on a loaded machine one poll may catch a late one."""
    return all((peer.get("position") or {}).get("age_s", math.inf) < 2.5
               for peer in answer.get("peers", []))


def logs(folder: Path) -> str:
    return "\n".join(f"--- {p.name}\n{p.read_text()[-3000:]}" for p in sorted(folder.glob("*.err")))
