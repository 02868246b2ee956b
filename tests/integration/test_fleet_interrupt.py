"""Operator checks (audit 12): Ctrl-C while ``uav-sitl fleet`` comes up.

Before: an operator who pressed Ctrl-C while the launcher waited for the vehicles, the
drones or the warm-up got exit status 1 and "stopped (SIGINT) while waiting for ...", as if
the fleet had failed. Now: the same line says no mission ran, the exit status is 0, and no
process of the run is left.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.fleet_checks import processes_of

FLEET = Path(sys.executable).parent / "uav-sitl"


@pytest.mark.timeout(120)
def test_ctrl_c_while_the_fleet_comes_up_is_a_clean_stop(tmp_path: Path) -> None:
    if not FLEET.exists():
        pytest.skip(f"{FLEET} missing: install the project in this venv")
    run_dir = tmp_path / "run"
    proc = subprocess.Popen([str(FLEET), "fleet", "--drones", "1", "--out", str(run_dir),
                             "--quiet", "--rate", "3"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        assert proc.stdout is not None
        for line in proc.stdout:  # everything before the waits is printed at once
            if line.startswith("constraint:"):
                break
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    assert "Traceback" not in err
    errors = [x for x in err.splitlines() if x.startswith("uav-sitl fleet:")]
    assert len(errors) == 1 and errors[0].startswith("uav-sitl fleet: stopped (SIGINT) while "
                                                     "waiting for "), err
    assert errors[0].endswith("; no mission ran")
    deadline = time.monotonic() + 10
    while processes_of(run_dir):
        assert time.monotonic() < deadline, processes_of(run_dir)
        time.sleep(0.2)
