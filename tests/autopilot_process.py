"""An autopilot (a real SITL or ``uav-sitl vehicle``) that a test starts, kills and starts
again with the same ports: ``UAV_TEST_AUTOPILOT_CMD`` (docs/companion.md, "Testing against a
real autopilot")."""

from __future__ import annotations

import contextlib
import os
import shlex
import signal
import subprocess
from dataclasses import dataclass
from pathlib import Path

__all__ = ["AutopilotProcess", "from_environment"]


@dataclass
class AutopilotProcess:
    """An autopilot the test starts, kills and starts again (same ports)."""

    argv: list[str]
    log: Path
    proc: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        with self.log.open("ab") as out:
            self.proc = subprocess.Popen(self.argv, stdout=out, stderr=subprocess.STDOUT,
                                         start_new_session=True)

    def stop(self) -> None:
        if self.proc is None:
            return
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.proc.pid, signal.SIGKILL)
        self.proc.wait(10)
        self.proc = None


def from_environment(log: Path) -> AutopilotProcess | None:
    """The ``UAV_TEST_AUTOPILOT_CMD`` autopilot (None: not set, a SITL the user runs)."""
    cmd = os.environ.get("UAV_TEST_AUTOPILOT_CMD", "")
    return AutopilotProcess(shlex.split(cmd), log) if cmd else None
