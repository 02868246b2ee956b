"""Start-up and shut-down of `uav-companion` processes in tests, written once.

The integration tests run the worktree's console script (not another checkout's), give it a
config whose ``[ground_station]`` table points at a test ground station with the test keys,
stop it with SIGTERM as systemd would, and wait for effects while it runs.
"""

from __future__ import annotations

import asyncio
import base64
import json
import os
import signal
import subprocess
import sys
import time
import urllib.request
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from tests.keys import TEST_COMMAND_PUB


def console_script(name: str) -> str:
    """The path of this venv's console script ``name`` (the test skips when it is missing)."""
    path = Path(sys.executable).parent / name
    if not path.exists():
        pytest.skip(f"{path} missing: install the project in this venv (make .venv/.installed)")
    return str(path)


def station_api(base_url: str, token: str, method: str, path: str, body: Any = None) -> Any:
    """One call of a running ``uav-ground-station``'s JSON API with its control token."""
    data = None if body is None else json.dumps(body).encode()
    request = urllib.request.Request(
        base_url + path, data=data, method=method,
        headers={"Authorization": f"Bearer {token}", "Content-Type": "application/json"})
    with urllib.request.urlopen(request, timeout=10) as resp:
        return json.loads(resp.read())


SCRIPT = Path(sys.executable).parent / "uav-companion"
COMPANION = [str(SCRIPT)] if SCRIPT.exists() else [sys.executable, "-m", "companion.cli"]


def ground_station_toml(port: int, *, fleet_id: int, fleet_key: bytes) -> str:
    """The companion's ``[ground_station]`` table for a ground station on 127.0.0.1:port."""
    return "\n".join([
        "[ground_station]",
        'host = "127.0.0.1"',
        f"port = {port}",
        f"fleet_id = {fleet_id}",
        f'fleet_key = "{fleet_key.decode()}"',
        f'command_public_key = "{base64.b64encode(TEST_COMMAND_PUB).decode()}"',
        'listen_host = "127.0.0.1"',
    ])


def start_companion(config: Path, *, json_logs: bool = False) -> subprocess.Popen[str]:
    """`uav-companion run` with stderr piped (read it with :func:`stop_companion`)."""
    logs = ["--log-format", "json"] if json_logs else []
    return subprocess.Popen([*COMPANION, *logs, "run", "--config", str(config)],
                            stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})


def stop_companion(proc: subprocess.Popen[str]) -> tuple[int, str]:
    """SIGTERM, then its exit code and stderr; a process that hangs is killed (code -9)."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
    try:
        _, err = proc.communicate(timeout=20)
    except subprocess.TimeoutExpired:
        proc.kill()
        _, err = proc.communicate()
        return -9, err
    return proc.returncode, err


async def until(predicate: Callable[[], object], timeout_s: float,
                proc: subprocess.Popen[str], *, poll_s: float = 0.1) -> None:
    """Wait for ``predicate``; fail with the companion's stderr if it exits or time runs out."""
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if proc.poll() is not None:
            _, err = stop_companion(proc)
            pytest.fail(f"companion exited early ({proc.returncode}):\n{err[-3000:]}")
        if time.monotonic() > deadline:
            _, err = stop_companion(proc)
            pytest.fail(f"condition not met in {timeout_s} s; companion stderr:\n{err[-3000:]}")
        await asyncio.sleep(poll_s)
