"""``uav-sitl fleet`` starts the mission only once every companion's optimiser is warm.

Real processes (launcher, vehicles, companions, station). On the warm numba cache the install
leaves (``make`` runs ``companion.warm_cache``) the default suite's two-drone run
(``test_fleet_e2e.py``) checks the order in every companion's log and the launcher's lines.
Here the companions get an empty cache of their own, so they really compile (about a minute
for two on a loaded 2-core machine): the launcher waits through it, saying so, and each
drone's images reach the station within the 10 s mission, not after the compile (before the
wait, a 30 s demo on a cold cache delivered no image at all).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from tests.fleet_checks import warm_before_start, warm_up_progress

FLEET = [sys.executable, "-m", "sitl.cli", "fleet"]
LIGHT = ["--rate", "3", "--mcts-iterations", "100", "--relay-rate", "0", "--first-fix", "0",
         "--quiet"]


def _fleet(run_dir: Path, *args: str, env: dict[str, str] | None = None,
           timeout_s: float) -> tuple[str, dict[str, Any]]:
    proc = subprocess.run([*FLEET, "--out", str(run_dir), *LIGHT, *args], capture_output=True,
                          text=True, timeout=timeout_s, check=False, env=env)
    assert proc.returncode == 0, f"stdout:\n{proc.stdout[-3000:]}\nstderr:\n{proc.stderr[-3000:]}"
    return proc.stdout, json.loads((run_dir / "summary.json").read_text())


@pytest.mark.slow
@pytest.mark.timeout(400)
def test_on_a_cold_cache_the_launcher_waits_and_images_flow_from_the_start(
        tmp_path: Path) -> None:
    cache = tmp_path / "numba-cache"
    cache.mkdir()
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}  # nothing compiled yet
    run_dir = tmp_path / "run"
    stdout, summary = _fleet(run_dir, "--drones", "2", "--duration", "10", env=env,
                             timeout_s=380)
    progress = warm_up_progress(stdout, 2)
    assert progress[0].startswith("waiting for 2 companions to warm up (optimiser compiling) ")
    for drone in ("drone1", "drone2"):
        warm_before_start(run_dir, drone)
        assert summary["drones"][drone]["received"] > 0, summary["drones"][drone]
    print("\n".join(progress))
