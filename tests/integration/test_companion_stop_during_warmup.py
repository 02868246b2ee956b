"""SIGTERM while the optimiser warms up stops ``uav-companion`` at once.

On a cold numba cache the warm-up compiles for 10-70 s. The companion used to log "stopped"
and then hang at interpreter exit until the compiler finished (its decider thread was a
ThreadPoolExecutor worker, which Python joins), so a supervisor's stop timeout ended it with
SIGKILL; in the tests this showed as the command-replay test's companion exiting -9 on a
fresh checkout. Real process, an empty cache of its own, SIGTERM as systemd sends it.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import time
from pathlib import Path

import pytest

from tests.companion_process import COMPANION, ground_station_toml

KEY = b"stop-during-warm-up-fleet-key"


@pytest.mark.timeout(120)
def test_sigterm_during_the_warm_up_exits_promptly(tmp_path: Path) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as gs, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as autopilot:
        gs.bind(("127.0.0.1", 0))
        autopilot.bind(("127.0.0.1", 0))  # nobody answers MAVLink here
        config = tmp_path / "d1.toml"
        config.write_text(f"""
[drone]
id = "d1"
[mavlink]
url = "udpout:127.0.0.1:{autopilot.getsockname()[1]}"
[camera]
enabled = false
[mission]
spec = "builtin:image_streaming"
{ground_station_toml(gs.getsockname()[1], fleet_id=5, fleet_key=KEY)}
""")
        cache = tmp_path / "numba-cache"
        cache.mkdir()
        err_path = tmp_path / "companion.err"
        with err_path.open("w") as err:
            proc = subprocess.Popen(
                [*COMPANION, "run", "--config", str(config)], stdout=subprocess.DEVNULL,
                stderr=err, text=True,
                env={**os.environ, "PYTHONUNBUFFERED": "1", "NUMBA_CACHE_DIR": str(cache)})
        try:
            deadline = time.monotonic() + 60.0
            while "mavlink connection opened" not in err_path.read_text():  # warm-up next
                assert proc.poll() is None, err_path.read_text()[-3000:]
                assert time.monotonic() < deadline, err_path.read_text()[-3000:]
                time.sleep(0.05)
            time.sleep(0.5)  # into the compile (it takes seconds: nothing is cached)
            t_term = time.monotonic()
            proc.send_signal(signal.SIGTERM)
            code = proc.wait(timeout=60)
            took = time.monotonic() - t_term
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    text = err_path.read_text()
    assert "optimiser warm-up unfinished" in text, text[-3000:]  # stopped while compiling
    assert "companion d1 stopped" in text and code == 0, text[-3000:]
    assert took < 10.0, f"exit took {took:.1f} s after SIGTERM:\n{text[-3000:]}"
    assert "Traceback" not in text
