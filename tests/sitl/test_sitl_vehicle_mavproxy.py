"""Acceptance with MAVProxy (optional: it is not a project dependency, because its wheel pulls
opencv-python and vtk). Runs when ``mavproxy.py`` is on PATH or ``UAV_SITL_MAVPROXY`` names
it, e.g. after ``pip install --no-deps --target /tmp/mpx MAVProxy pyserial`` with
``UAV_SITL_MAVPROXY=/tmp/mpx/bin/mavproxy.py PYTHONPATH=/tmp/mpx``."""

from __future__ import annotations

import os
import queue
import shutil
import subprocess
import sys
import threading
import time

import pytest

from sitl.vehicle.flavour import ARDUPILOT
from tests.processes import terminate

MAVPROXY = os.environ.get("UAV_SITL_MAVPROXY") or shutil.which("mavproxy.py")
pytestmark = pytest.mark.skipif(MAVPROXY is None, reason="MAVProxy is not installed")

WAYPOINTS = """QGC WPL 110
0\t1\t0\t16\t0\t0\t0\t0\t47.397742\t8.545594\t488.0\t1
1\t0\t3\t22\t0\t0\t0\t0\t0\t0\t10.0\t1
2\t0\t3\t16\t0\t0\t0\t0\t47.397967\t8.545594\t10.0\t1
3\t0\t3\t16\t0\t0\t0\t0\t47.397967\t8.545930\t10.0\t1
4\t0\t3\t21\t0\t0\t0\t0\t47.397742\t8.545930\t0.0\t1
"""


class Expect:
    """Feed MAVProxy commands and wait for its console lines (no fixed sleeps)."""

    def __init__(self, proc: subprocess.Popen[str]) -> None:
        self.proc = proc
        self.lines: queue.Queue[str] = queue.Queue()
        self.seen: list[str] = []
        self._mark = 0
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.put(line.rstrip())

    def send(self, command: str) -> None:
        assert self.proc.stdin is not None
        self._mark = len(self.seen)
        self.proc.stdin.write(command + "\n")
        self.proc.stdin.flush()

    def expect(self, text: str, timeout: float = 20.0) -> str:
        """The first line since the last command containing ``text`` (lines may come in any
        order: MAVProxy reports a mode change only with the next heartbeat)."""
        for line in self.seen[self._mark:]:
            if text in line:
                return line
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                line = self.lines.get(timeout=0.2)
            except queue.Empty:
                continue
            self.seen.append(line)
            if text in line:
                return line
        raise AssertionError(f"MAVProxy never printed {text!r}; last lines: {self.seen[-15:]}")


@pytest.mark.timeout(120)
def test_mavproxy_reads_params_loads_and_flies_a_mission_and_lands(vehicle_process, tmp_path):
    vehicle = vehicle_process("--flavour", "ardupilot", "--speedup", "10")
    wp = tmp_path / "mission.txt"
    wp.write_text(WAYPOINTS)
    proc = subprocess.Popen(
        [sys.executable, str(MAVPROXY), f"--master=udpout:127.0.0.1:{vehicle.port}",
         "--default-modules=link,param,mode,arm,cmdlong,wp,misc",
         f"--state-basedir={tmp_path}"],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        env=dict(os.environ, MAVLINK20="1"), cwd=tmp_path)
    try:
        mp = Expect(proc)
        mp.expect("online system 1")
        mp.expect(f"Received {len(ARDUPILOT.params)} parameters")  # all of them
        mp.send(f"wp load {wp}")
        mp.expect("MISSION_ACK: TYPE_MISSION: ACCEPTED")
        mp.send("mode loiter")
        mp.expect("Mode LOITER")
        mp.send("arm throttle")
        mp.expect("ARMED")
        mp.send("mode auto")
        mp.expect("Mode AUTO")
        mp.expect("waypoint 4")
        mp.expect("DISARMED", timeout=30)
        mp.send("wp list")
        mp.expect("Saved 5 waypoints")
        mp.send("exit")
    finally:
        terminate(proc)
