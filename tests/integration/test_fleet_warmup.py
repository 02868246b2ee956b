"""``uav-sitl fleet`` starts the mission only once every companion's optimiser is warm.

Real processes (launcher, vehicles, companions, station). The default test runs on the warm
numba cache the install leaves (``make`` runs ``companion.warm_cache``): every companion logs
its warm-up before the start command, the launcher says it waited, and the station's
``/api/fleet`` showed ``optimiser_ready`` (so the summary's first images come early). The
``slow`` one gives the companions an empty cache of their own, so they really compile (about a
minute for two on a loaded 2-core machine): the launcher waits through it, and each drone's
images reach the station in the first seconds of the mission, not after the compile.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

FLEET = [sys.executable, "-m", "sitl.cli", "fleet"]
LIGHT = ["--rate", "3", "--mcts-iterations", "100", "--relay-rate", "0", "--first-fix", "0",
         "--quiet"]


def _fleet(run_dir: Path, *args: str, env: dict[str, str] | None = None,
           timeout_s: float) -> tuple[str, dict[str, Any]]:
    proc = subprocess.run([*FLEET, "--out", str(run_dir), *LIGHT, *args], capture_output=True,
                          text=True, timeout=timeout_s, check=False, env=env)
    assert proc.returncode == 0, f"stdout:\n{proc.stdout[-3000:]}\nstderr:\n{proc.stderr[-3000:]}"
    return proc.stdout, json.loads((run_dir / "summary.json").read_text())


def _warm_before_start(run_dir: Path, drone: str) -> None:
    """The companion's own log: "optimiser warmed up" comes before it takes the start."""
    lines = (run_dir / "logs" / f"{drone}.log").read_text().splitlines()
    warm = [i for i, line in enumerate(lines) if "optimiser warmed up in" in line]
    start = [i for i, line in enumerate(lines) if "command start #" in line]
    assert warm and start, "\n".join(lines[-40:])
    assert warm[0] < start[0], "\n".join(lines[warm[0] - 5:warm[0] + 5])


def _progress(stdout: str, n: int) -> list[str]:
    """The launcher's warm-up lines, which come before "mission started"."""
    lines = stdout.splitlines()
    started = next(i for i, line in enumerate(lines) if line.startswith("mission started"))
    warm = [line for line in lines[:started] if "companions" in line and "warm" in line]
    assert warm and warm[-1].startswith(f"companions warm: {n}/{n}"), stdout[-3000:]
    return warm


@pytest.mark.timeout(150)
def test_the_mission_starts_after_every_optimiser_is_warm(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    stdout, summary = _fleet(run_dir, "--drones", "2", "--duration", "3", timeout_s=140)
    _progress(stdout, 2)
    for drone in ("drone1", "drone2"):
        _warm_before_start(run_dir, drone)
    assert summary["failure"] is None


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
    progress = _progress(stdout, 2)
    assert progress[0].startswith("waiting for 2 companions to warm up (optimiser compiling) ")
    for drone in ("drone1", "drone2"):
        _warm_before_start(run_dir, drone)
        assert summary["drones"][drone]["received"] > 0, summary["drones"][drone]
    print("\n".join(progress))
