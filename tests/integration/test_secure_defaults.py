"""Secure by default (issue 13 item 2): no built-in key. ``uav-ground-station run`` and
``uav-companion run`` without keys refuse with one line naming the exact command that makes
them, and that command works; a fleet run gets its own keys; binding every interface is
said out loud. Real console scripts of this checkout."""

from __future__ import annotations

import asyncio
import base64
import shlex
import signal
import socket
import stat
import subprocess
import sys
from pathlib import Path

import aiohttp

from companion.config import load_config as load_companion_config
from companion.protocol import wire
from companion.protocol.signing import decode_key_text, fleet_key_text, public_key_of
from ground_station.config import load_config as load_gs_config
from ground_station.config import missing_keys
from sitl.fleet import make_plan, parse_args
from sitl.fleet_config import write_run_configs

BIN = Path(sys.executable).parent
GS = [str(BIN / "uav-ground-station")] if (BIN / "uav-ground-station").exists() else [
    sys.executable, "-m", "ground_station.cli"]
COMPANION = [str(BIN / "uav-companion")] if (BIN / "uav-companion").exists() else [
    sys.executable, "-m", "companion.cli"]


def run(argv: list[str], cwd: Path, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    return subprocess.run(argv, cwd=cwd, capture_output=True, text=True, timeout=timeout)


def free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_there_is_no_built_in_key() -> None:
    assert not hasattr(wire, "DEMO_FLEET_KEY")
    source = (Path(wire.__file__).parents[2] / "companion").rglob("*.py")
    assert not any("uav-infodist-demo-fleet-key" in p.read_text() for p in source)


async def test_station_refuses_without_keys_and_the_named_command_makes_them(
    tmp_path: Path,
) -> None:
    udp_port, http_port = free_port(socket.SOCK_DGRAM), free_port(socket.SOCK_STREAM)
    config = tmp_path / "gs.toml"
    config.write_text(f'[ground_station]\ndata_dir = "data"\nudp_host = "0.0.0.0"\n'
                      f"udp_port = {udp_port}\nhttp_port = {http_port}\n")
    refused = run([*GS, "run", "--config", str(config)], tmp_path)
    assert refused.returncode == 2 and refused.stdout == ""
    lines = refused.stderr.strip().splitlines()
    assert len(lines) == 1 and "no fleet key" in lines[0], refused.stderr
    command = lines[0].split("`")[1]
    assert command == f"uav-ground-station keygen --data-dir {tmp_path / 'data'}"
    assert not (tmp_path / "data" / "token").exists()  # nothing shown once was wasted

    made = run([*GS, *shlex.split(command)[1:]], tmp_path)
    assert made.returncode == 0, made.stderr
    keys = tmp_path / "data" / "keys"
    assert stat.S_IMODE((keys / "fleet.key").stat().st_mode) == 0o600
    assert stat.S_IMODE((keys / "command.key").stat().st_mode) == 0o600
    seed = decode_key_text((keys / "command.key").read_bytes(), "command.key")
    assert decode_key_text((keys / "command.pub").read_bytes(), "pub") == public_key_of(seed)
    again = run([*GS, *shlex.split(command)[1:]], tmp_path)
    assert again.returncode == 1 and "exists" in again.stderr  # never overwrites a fleet's keys
    keyed = missing_keys(load_gs_config(config))
    assert not isinstance(keyed, str) and keyed.command_key == seed

    station = subprocess.Popen([*GS, "run", "--config", str(config)], cwd=tmp_path,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        async with asyncio.timeout(30), aiohttp.ClientSession() as session:
            while True:
                try:
                    async with session.get(f"http://127.0.0.1:{http_port}/api/stats") as r:
                        if r.status == 401:
                            break
                except aiohttp.ClientError:
                    pass
                await asyncio.sleep(0.1)
            # a one-time login link from the CLI opens a session on the running station
            link = run([*GS, "token", "--url", "--config", str(config)], tmp_path)
            url = link.stdout.strip()
            assert url.startswith(f"http://127.0.0.1:{http_port}/?login="), link.stderr
            async with session.get(url, allow_redirects=False) as r:
                assert r.status == 303 and r.headers["Location"].split("#key=")[0] == "/"
                assert "gs_session" in r.cookies and r.cookies["gs_session"]["httponly"]
            async with session.get(url, allow_redirects=False) as r:
                assert "gs_session" not in r.cookies  # once only
    finally:
        station.send_signal(signal.SIGINT)
        out, err = station.communicate(timeout=20)
    assert station.returncode == 0, err
    assert "udp_host is '0.0.0.0': listening on every network interface" in err
    assert "?login=" in out and "?token=" not in out


def test_companion_refuses_without_keys(tmp_path: Path) -> None:
    config = tmp_path / "companion.toml"
    config.write_text('[drone]\nid = "d1"\n[camera]\nenabled = false\n')
    result = run([*COMPANION, "--log-format", "text", "run", "--config", str(config)], tmp_path)
    assert result.returncode == 2
    errors = [line for line in result.stderr.splitlines() if "cannot start" in line]
    assert len(errors) == 1, result.stderr
    assert "ground_station.fleet_key_file is not set" in errors[0]
    assert "`uav-ground-station keygen --out keys`" in errors[0]
    assert "Traceback" not in result.stderr

    made = run([*GS, "keygen", "--out", "keys"], tmp_path)
    assert made.returncode == 0, made.stderr
    config.write_text('[drone]\nid = "d1"\n[camera]\nenabled = false\n[ground_station]\n'
                      'fleet_key_file = "keys/fleet.key"\n'
                      'command_public_key_file = "keys/command.pub"\n')
    loaded = load_companion_config(config)
    assert loaded.ground_station.command_public_key == base64.b64decode(
        (tmp_path / "keys" / "command.pub").read_bytes().rpartition(b": ")[2])


def test_every_fleet_run_has_its_own_keys(tmp_path: Path) -> None:
    seen = set()
    for name in ("a", "b"):
        plan = make_plan(parse_args(["--drones", "2"]), tmp_path / name)
        write_run_configs(plan)
        gs = load_gs_config(plan.gs_config_path)
        assert gs.fleet_key == fleet_key_text(plan.key_path.read_bytes(), "fleet.key")
        assert gs.command_key is not None
        for drone in plan.drones:
            cfg = load_companion_config(drone.config_path).ground_station
            assert cfg.fleet_key == gs.fleet_key
            assert cfg.command_public_key == public_key_of(gs.command_key)
        seen.add((gs.fleet_key, gs.command_key))
        assert stat.S_IMODE(plan.command_key_path.stat().st_mode) == 0o600
    assert len(seen) == 2
