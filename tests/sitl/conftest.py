"""Helpers for the SITL tests: an in-memory ground station for the sans-I/O vehicle core, and
a way to start ``uav-sitl vehicle`` as a real subprocess on a free port."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sitl.vehicle.core import VehicleConfig, VehicleCore
from tests.processes import terminate


class MemoryGcs:
    """A GCS (sysid 255) talking to a VehicleCore without sockets; time is explicit."""

    def __init__(self, core: VehicleCore) -> None:
        self.core = core
        self.now = 0.0
        self._tx = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
        self._rx = mavlink.MAVLink(None)
        self.received: list[Any] = []
        self.pump()

    def pump(self) -> None:
        for frame in self.core.datagrams_to_send():
            msgs = self._rx.parse_buffer(frame)
            assert msgs is not None and len(msgs) == 1, "one MAVLink frame per datagram"
            self.received.extend(msgs)

    def send(self, msg: Any) -> None:
        data = msg.pack(self._tx)
        self._tx.seq = (self._tx.seq + 1) % 256
        self.core.receive_datagram(data, ("127.0.0.1", 14551), self.now)
        self.pump()

    def run_until(self, t_end: float, *, stop: Callable[[], bool] | None = None) -> None:
        """Jump from timer to timer (as the shell would) until ``t_end`` or ``stop()``."""
        while True:
            deadline = self.core.get_timer()
            if deadline > t_end:
                break
            self.now = max(self.now, deadline)
            self.core.handle_timer(self.now)
            self.pump()
            if stop is not None and stop():
                return
        self.now = t_end

    def of_type(self, kind: str) -> list[Any]:
        return [m for m in self.received if m.get_type() == kind]

    def clear(self) -> None:
        self.received.clear()

    def command(self, command: int, *params: float) -> Any:
        """COMMAND_LONG and its COMMAND_ACK."""
        p = list(params) + [0.0] * (7 - len(params))
        before = len(self.of_type("COMMAND_ACK"))
        self.send(mavlink.MAVLink_command_long_message(1, 1, command, 0, *p))
        acks = self.of_type("COMMAND_ACK")
        assert len(acks) == before + 1, f"no COMMAND_ACK for command {command}"
        assert acks[-1].command == command
        return acks[-1]


@pytest.fixture
def make_gcs() -> Callable[..., MemoryGcs]:
    def make(**config: Any) -> MemoryGcs:
        # These tests fly at once; the boot without a fix has its own tests.
        config.setdefault("first_fix_s", 0.0)
        return MemoryGcs(VehicleCore(VehicleConfig(**config), now=0.0))

    return make


@dataclass
class VehicleProcess:
    proc: subprocess.Popen[str]
    records: list[dict[str, Any]]

    @property
    def port(self) -> int:
        return int(self.records[0]["port"])


@pytest.fixture
def vehicle_process() -> Iterator[Callable[..., VehicleProcess]]:
    """Start ``uav-sitl vehicle --port 0 ...`` and wait for its READY lines."""
    started: list[subprocess.Popen[str]] = []

    def start(*args: str, count: int = 1) -> VehicleProcess:
        env = dict(os.environ, MAVLINK20="1", PYTHONUNBUFFERED="1")
        fix = [] if "--first-fix" in args else ["--first-fix", "0"]
        proc = subprocess.Popen(
            [sys.executable, "-m", "sitl.cli", "vehicle", "--port", "0", "--count", str(count),
             *fix, *args],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        started.append(proc)
        records = []
        assert proc.stdout is not None
        for _ in range(count):
            line = proc.stdout.readline()
            assert line.startswith("READY "), f"vehicle did not start: {line!r}"
            records.append(json.loads(line.split(" ", 1)[1]))
        return VehicleProcess(proc=proc, records=records)

    yield start
    for proc in started:
        terminate(proc)
        for stream in (proc.stdout, proc.stderr):
            if stream is not None:
                stream.close()
