"""Operator checks (audit 12), fast tier: a real ``uav-ground-station run`` (default logging,
real UDP and HTTP) and drones that restart like companions do (a new boot epoch, their
memory of commands gone, ``mission: idle`` in their status). The product-tier version with
real companions is ``test_operator_restarts.py`` (slow).

Before: a restarted drone was sent only commands it had not acknowledged in its previous
life, so it never got the start back (it stayed idle while the station showed ``start:
done``); a station restarted mid-mission showed phase ``idle`` with no command.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import socket
import subprocess
import sys
from pathlib import Path
from typing import Any

import aiohttp
import pytest

from ground_station.fake_drone import FakeDrone
from tests.keys import TEST_COMMAND_PUB, TEST_FLEET_KEY, write_test_keys
from utility_specs.intervals import intervals_of, select_intervals

SCRIPT = Path(sys.executable).parent / "uav-ground-station"
STATION = [str(SCRIPT)] if SCRIPT.exists() else [sys.executable, "-m", "ground_station.cli"]
FLEET = 12


def free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Station:
    def __init__(self, tmp_path: Path) -> None:
        self.udp, http = free_port(socket.SOCK_DGRAM), free_port(socket.SOCK_STREAM)
        write_test_keys(tmp_path / "data" / "keys")
        self.config = tmp_path / "gs.toml"
        self.config.write_text(
            f'[ground_station]\nfleet_id = {FLEET}\ndata_dir = "data"\nmission = "ops"\n'
            f'udp_host = "127.0.0.1"\nudp_port = {self.udp}\nhttp_port = {http}\n'
            "fsync = false\ncommand_retry_s = 0.2\ncommand_ttl_s = 2.0\nlink_lost_s = 1.0\n"
            "command_reply_timeout_s = 1.0\n")
        self.http = f"http://127.0.0.1:{http}"
        self.token_file = tmp_path / "data" / "token"
        self.proc: subprocess.Popen[str] | None = None

    async def start(self) -> None:
        self.proc = subprocess.Popen([*STATION, "run", "--config", str(self.config)],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                     text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
        async with asyncio.timeout(20):
            while True:
                try:
                    await self.api("GET", "/api/stats")
                    return
                except (OSError, aiohttp.ClientError):
                    await asyncio.sleep(0.1)

    def stop(self) -> str:
        assert self.proc is not None
        self.proc.send_signal(signal.SIGINT)
        _, err = self.proc.communicate(timeout=20)
        assert self.proc.returncode == 0, err[-2000:]
        assert "Traceback" not in err
        return err

    async def api(self, method: str, path: str, body: Any = None) -> Any:
        headers = {"Authorization": f"Bearer {self.token_file.read_text().strip()}"}
        async with aiohttp.ClientSession() as session, session.request(
                method, self.http + path, json=body, headers=headers) as resp:
            resp.raise_for_status()
            return await resp.json()


async def drone(station: Station) -> FakeDrone:
    """A freshly booted drone1 (new epoch, remembers no command) that says it is idle."""
    fake = FakeDrone("drone1", fleet_id=FLEET, key=TEST_FLEET_KEY,
                     ground=("127.0.0.1", station.udp), command_public_key=TEST_COMMAND_PUB)
    await fake.open()
    fake.send_telemetry("status", {"mode": "MISSION", "mission": "idle"})
    return fake


async def until(predicate: Any, timeout_s: float = 10.0) -> None:
    async with asyncio.timeout(timeout_s):
        while not await predicate():
            await asyncio.sleep(0.05)


def names(fake: FakeDrone) -> list[str]:
    return [c.command.name for c in fake.commands]


@pytest.mark.timeout(90)
async def test_restarted_drones_and_station_keep_the_mission(tmp_path: Path) -> None:
    station = Station(tmp_path)
    logs = ""
    await station.start()
    first = await drone(station)
    try:
        await until(lambda: _heard(station))
        start = (await station.api("POST", "/api/mission/start", {}))["command"]
        params = (await station.api("POST", "/api/mission/params",
                                    {"params": "mcts_iterations=7"}))["command"]
        await until(lambda: _done(station, 2))
        first.close()
        await asyncio.sleep(1.1)  # a boot takes longer: packet numbers start at int(now) << 32

        # the drone restarts: a new epoch; it gets the start and the parameters again
        second = await drone(station)
        await until(lambda: _async(len(second.commands) >= 2))
        assert names(second)[:2] == ["start", "set_params"]
        assert second.commands[1].command.args == {"mcts_iterations": 7}
        await until(lambda: _done(station, 2))  # its new results, not the old life's

        # the station restarts (Ctrl-C, same data dir): the mission is still there
        logs = station.stop()
        await station.start()
        mission = await station.api("GET", "/api/mission")
        assert mission["phase"] == "running" and mission["params"] == {"mcts_iterations": 7}
        assert [c["command_id"] for c in mission["commands"]] == [start["command_id"],
                                                                  params["command_id"]]
        assert all(c["summary"]["done"] == 1 for c in mission["commands"])
        second.close()
        await asyncio.sleep(1.1)

        # a drone that restarted while the station was down says it is idle: it rejoins
        third = await drone(station)
        await until(lambda: _async(len(third.commands) >= 2))
        assert names(third)[:2] == ["start", "set_params"]
        third.close()
    finally:
        first.close()
        if station.proc is not None and station.proc.poll() is None:
            logs += station.stop()
    assert "drone1 restarted: sending it the mission's commands again" in logs
    assert "drone1 says its mission is idle" in logs
    # the evaluated interval spans the restart: from the start command to the last stop
    # (before: the first stop's t_end closed it, and what came after counted nowhere)
    log = tmp_path / "data" / "missions" / "ops" / "mission_log.jsonl"
    records = [json.loads(x) for x in log.read_text().splitlines() if x.strip()]
    bounds = [(r["mission"].get("t_start"), r["mission"].get("t_end"))
              for r in records if "mission" in r]
    [chosen] = select_intervals([intervals_of(bounds, "gs")], [], None).chosen
    assert chosen.t_start == start["t_exec"] and chosen.t_end == bounds[-1][1]
    first_stop = next(t_end for _, t_end in bounds if t_end is not None)
    after = [r["t_rcv"] for r in records if "sender" in r and r["t_rcv"] > first_stop]
    assert after and all(chosen.t_start <= t <= chosen.t_end for t in after)


@pytest.mark.timeout(60)
async def test_a_drone_back_from_an_outage_gets_the_expired_params(tmp_path: Path) -> None:
    """Before: a set_params issued while a drone was out of reach for longer than the
    command's TTL never reached it; the station showed ``no reply`` for good."""
    station = Station(tmp_path)
    await station.start()
    fake = await drone(station)
    try:
        fake.send_telemetry("status", {"mission": "running"})
        await until(lambda: _heard(station))
        fake.datagram_received = lambda *_: None  # type: ignore[method-assign]  # out of reach
        await station.api("POST", "/api/mission/params", {"params": "alpha=5"})
        await asyncio.sleep(3.5)  # lost (1 s), and the command expired (2 s after t_exec)
        state = await station.api("GET", "/api/mission")
        assert state["commands"][0]["summary"]["no reply"] == 1 and fake.commands == []
        del fake.datagram_received  # back in reach
        fake.send_telemetry("status", {"mission": "running"})
        await until(lambda: _done(station, 1))
        assert fake.commands and all(c.command.args == {"alpha": 5} for c in fake.commands)
    finally:
        fake.close()
        logs = station.stop()
    assert "drone1 is back: sending it the mission's commands it has not answered" in logs
    # a stop says in one line what the run kept (it said nothing): the three statuses
    assert "stopped: 3 messages stored (0 images), 0 not stored, 0 refused" in logs


async def _async(value: bool) -> bool:
    return value


async def _heard(station: Station) -> bool:
    return bool((await station.api("GET", "/api/mission"))["drones"])


async def _done(station: Station, commands: int) -> bool:
    state = await station.api("GET", "/api/mission")
    return len(state["commands"]) == commands and all(
        c["summary"]["done"] == 1 for c in state["commands"])


@pytest.mark.timeout(60)
async def test_a_station_restart_raises_no_old_alert_again(tmp_path: Path) -> None:
    """Before: after a clean restart (Ctrl-C, same data dir) every drone's first second of
    datagrams was refused and alerted as ``replayed`` (22 in one operator run), and every
    drone "joined" again. A restart is not news: the drone streams on through it, nothing it
    sends after the stop is refused, and no alert of the first run comes back."""
    station = Station(tmp_path)
    await station.start()
    fake = await drone(station)
    streaming = True

    async def stream() -> None:  # statuses at 20 Hz, through the station's downtime
        while streaming:
            fake.send_telemetry("status", {"mode": "MISSION", "mission": "running"})
            await asyncio.sleep(0.05)

    sender = asyncio.create_task(stream())
    try:
        await until(lambda: _heard(station))
        await station.api("POST", "/api/mission/start", {})
        await until(lambda: _done(station, 1))
        station.stop()
        await station.start()
        t_back = (await station.api("GET", "/api/stats"))["decoder"]
        await asyncio.sleep(2.5)
        stats = (await station.api("GET", "/api/stats"))["decoder"]
        alerts = (await station.api("GET", "/api/fleet"))["alerts"]
    finally:
        streaming = False
        await sender
        fake.close()
        station.stop()
    assert stats["accepted"] > t_back["accepted"] + 30  # it was heard all along
    assert stats.get("replayed", 0) == 0, stats
    assert [a["text"] for a in alerts] == [], alerts


@pytest.mark.timeout(60)
async def test_a_mission_the_station_opened_itself_survives_a_restart(tmp_path: Path) -> None:
    """No start command: the station opens the mission with the first message. Before, the
    stop's ``t_end`` closed it for good (the restarted station wrote no start), so
    ``uav-utility evaluate`` took [first message, first stop] and what came after counted
    nowhere; started with a command, a mission survived (above)."""
    station = Station(tmp_path)
    await station.start()
    fake = await drone(station)
    try:
        for stored in (6, 5):  # two station runs (the first also has the drone's status)
            for _ in range(5):
                fake.send_telemetry("battery", {"level": 0.5})
                await asyncio.sleep(0.05)
            await until(lambda n=stored: _stored(station, n))  # type: ignore[misc]
            station.stop()
            await station.start()
        fake.send_telemetry("battery", {"level": 0.5})
        await until(lambda: _stored(station, 1))
    finally:
        fake.close()
        station.stop()
    log = tmp_path / "data" / "missions" / "ops" / "mission_log.jsonl"
    records = [json.loads(x) for x in log.read_text().splitlines() if x.strip()]
    bounds = [(r["mission"].get("t_start"), r["mission"].get("t_end"))
              for r in records if "mission" in r]
    received = [r["t_rcv"] for r in records if "sender" in r]
    assert len(received) == 6 + 5 + 1
    [chosen] = select_intervals([intervals_of(bounds, "gs")], [], None).chosen
    assert chosen.t_start == bounds[0][0] and chosen.t_end == bounds[-1][1]
    assert all(chosen.t_start <= t <= chosen.t_end for t in received)


async def _stored(station: Station, n: int) -> bool:
    stats = await station.api("GET", "/api/stats")
    return bool(stats["storage"]["written"] - stats["storage"]["not_stored"] >= n)
