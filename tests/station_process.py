"""A real ``uav-ground-station run`` for tests that attack it over sockets: default (INFO)
logging to a file, ports picked by the OS, the test keys, an optional TOML config."""

from __future__ import annotations

import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from tests.keys import write_test_keys
from tests.processes import interrupt

STATION = Path(sys.executable).parent / "uav-ground-station"

KEPT_ALIVE = b"GET /api/stats HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"
"""A request the station answers (401 without a token) before the one under test."""


def raw_reply(port: int, request: bytes, *, kept_alive: bool = True) -> bytes:
    """Everything the station answers to ``request`` until it closes the connection.

    ``kept_alive``: send it on a connection that has served :data:`KEPT_ALIVE` first, since
    aiohttp logs a connection's first unparsable request at DEBUG only (TLS to a plain port).
    """
    with socket.create_connection(("127.0.0.1", port), timeout=10) as conn:
        if kept_alive:
            conn.sendall(KEPT_ALIVE)
            assert conn.recv(65536).startswith(b"HTTP/1.1 401 ")
        conn.sendall(request)
        reply = b""
        while chunk := conn.recv(65536):
            reply += chunk
    return reply


@dataclass(frozen=True)
class Station:
    proc: subprocess.Popen[str]
    port: int
    token: str
    log: Path
    dashboard_line: str = ""

    def log_text(self) -> str:
        time.sleep(0.2)  # the last lines reach the file
        return self.log.read_text()


@contextmanager
def running_station(tmp_path: Path, config_toml: str = "") -> Iterator[Station]:
    """The station on 127.0.0.1 (HTTP and UDP ports 0); stopped with Ctrl-C at the end."""
    data = tmp_path / "data"
    write_test_keys(data / "keys")
    args = [str(STATION), "run", "--data-dir", str(data), "--udp-port", "0",
            "--http-port", "0"]
    if config_toml:
        config = tmp_path / "station.toml"
        config.write_text(config_toml)
        args += ["--config", str(config)]
    log = tmp_path / "station.log"
    with open(log, "w") as stderr:
        proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=stderr, text=True)
    try:
        assert proc.stdout is not None
        line = next((x for x in proc.stdout if x.startswith("dashboard:")), None)
        assert line is not None, log.read_text()
        port = int(line.split("/")[2].split(":")[1])
        token = (data / "token").read_text().strip()
        yield Station(proc, port, token, log, line.strip())
    finally:
        interrupt(proc, timeout_s=20)
