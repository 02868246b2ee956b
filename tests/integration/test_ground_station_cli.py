"""`uav-ground-station` as real subprocesses: run, shell, token, export."""

from __future__ import annotations

import asyncio
import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import aiohttp

from ground_station.fake_drone import FakeDrone, synthetic_jpeg
from tests.keys import TEST_COMMAND_PUB, write_test_keys
from tests.processes import interrupt

KEY = "cli-integration-fleet-key-000"
BIN = [sys.executable, "-m", "ground_station.cli"]


def free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


async def wait_http(url: str, timeout: float = 15.0) -> None:
    async with asyncio.timeout(timeout), aiohttp.ClientSession() as session:
        while True:
            try:
                async with session.get(url) as resp:
                    if resp.status in (200, 401):
                        return
            except aiohttp.ClientError:
                pass
            await asyncio.sleep(0.1)


async def run_cli(*args: str) -> tuple[int, str, str]:
    proc = await asyncio.create_subprocess_exec(
        *BIN, *args, stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    out, err = await asyncio.wait_for(proc.communicate(), timeout=30)
    return proc.returncode or 0, out.decode(), err.decode()


async def test_run_shell_token_export(tmp_path: Path) -> None:
    udp_port, http_port = free_port(socket.SOCK_DGRAM), free_port(socket.SOCK_STREAM)
    config = tmp_path / "gs.toml"
    write_test_keys(tmp_path / "data" / "keys", fleet_key=KEY.encode())
    config.write_text(
        "[ground_station]\n"
        f'fleet_key = "{KEY}"\nfleet_id = 5\ndata_dir = "data"\nmission = "cli"\n'
        f'udp_host = "127.0.0.1"\nudp_port = {udp_port}\nhttp_port = {http_port}\n'
        "report_interval_s = 0.1\ncommand_retry_s = 0.2\n"
    )
    station = subprocess.Popen(
        [*BIN, "run", "--config", str(config)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        first_line = station.stdout.readline() if station.stdout else ""  # type: ignore[union-attr]
        assert first_line.startswith("control token (shown once")
        token = first_line.rsplit(": ", 1)[1].strip()
        token_file = tmp_path / "data" / "token"
        assert token_file.read_text().strip() == token
        assert oct(token_file.stat().st_mode & 0o777) == "0o600"
        await wait_http(f"http://127.0.0.1:{http_port}/api/stats")

        drone = FakeDrone("uav1", fleet_id=5, key=KEY.encode(), ground=("127.0.0.1", udp_port),
                          command_public_key=TEST_COMMAND_PUB)
        await drone.open()
        jpeg = synthetic_jpeg(1, red=0.3, label="uav1")
        drone.send_image(jpeg, data={"red": 0.3, "lat": 51.1, "lon": 17.0, "alt": 30.0})
        drone.send_telemetry("battery", {"level": 0.9})

        code, out, err = await run_cli("shell", "--config", str(config), "-c", "n 1; s now; q")
        assert code == 0, err
        assert "1 drone(s): uav1" in out and "Starting mission" in out
        command = await drone.wait_command(timeout=5)
        assert command.command.name == "start"
        drone.close()

        code, out, _ = await run_cli("token", "--config", str(config))
        assert (code, out.strip()) == (0, token)
    finally:
        code = interrupt(station, timeout_s=15)
    assert code == 0
    code, out, err = await run_cli(
        "export", "cli", "--out", str(tmp_path / "out"), "--config", str(config)
    )
    assert code == 0, err
    assert "exported 1 images" in out
    assert (tmp_path / "out" / "images" / "uav1_000000001.jpg").read_bytes() == jpeg
    csv_lines = (tmp_path / "out" / "geotags.csv").read_text().splitlines()
    assert csv_lines[0].startswith("image,latitude,longitude,altitude")
    assert csv_lines[1].startswith("images/uav1_000000001.jpg,51.1,17.0,30.0")

    # the mission log scores with the utility model's own evaluator
    log_path = tmp_path / "data" / "missions" / "cli" / "mission_log.jsonl"
    proc = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "utility_specs.cli",
        "evaluate",
        "--spec",
        "image_streaming",
        "--ignore-unknown-types",
        "--json",
        str(log_path),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    out_b, err_b = await asyncio.wait_for(proc.communicate(), timeout=60)
    assert proc.returncode == 0, err_b.decode()
    scores = json.loads(out_b)
    assert scores["total"] > 0 and set(scores["per_receiver"]) == {"gs"}

    # restart does not print the token again
    again = subprocess.Popen(
        [*BIN, "run", "--config", str(config)],
        stdout=subprocess.PIPE,
        text=True,
        stderr=subprocess.DEVNULL,
        env={**os.environ},
    )
    try:
        line = again.stdout.readline() if again.stdout else ""  # type: ignore[union-attr]
        assert token not in line and line.startswith("dashboard:")
    finally:
        assert interrupt(again, timeout_s=15) == 0


async def test_config_error_exit_code(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("[ground_station]\nudp_port = 'x'\n")
    code, _, err = await run_cli("run", "--config", str(bad))
    assert code == 2
    assert str(bad) in err and "'udp_port'" in err and "an integer port" in err


async def test_a_token_for_a_folder_no_station_used_says_so(tmp_path: Path) -> None:
    """A newcomer typed ``token --data-dir`` with a typo and got a fresh token that no
    running station knows; the line that says a token was made now says that too."""
    code, out, err = await run_cli("token", "--data-dir", str(tmp_path / "dtaa"))
    assert code == 0 and len(out.strip()) >= 16
    assert "no station has run on this data folder yet" in err
    code, _, err = await run_cli("token", "--data-dir", str(tmp_path / "dtaa"))
    assert code == 0 and err == ""  # the same token again, nothing new to say
