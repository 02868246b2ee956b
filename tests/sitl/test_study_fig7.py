"""``uav-sitl study fig7.3`` and ``fig7.4``: image streaming with MCTS on the shared channel."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from companion.middleware.baselines import RandomDrop
from sitl.netsim import ChannelConfig, SimAgent, StreamConfig, simulate

SITL = Path(sys.executable).parent / "uav-sitl"


class Recorder(RandomDrop):
    """Sends everything and remembers whose deliveries it was told about."""

    def __init__(self) -> None:
        super().__init__(0.0, rng=np.random.default_rng(0))
        self.heard: set[str] = set()

    def on_delivered(self, messages: Any, now: float) -> None:
        self.heard.update(m.sender for m in messages)


def test_background_traffic_shares_the_medium_but_is_not_overheard() -> None:
    drone, background = Recorder(), Recorder()
    agents = [SimAgent(name="uav0", policy=drone, streams=[
                  StreamConfig(type="image", period_s=0.1, size=1000)]),
              SimAgent(name="bg", policy=background, overheard=False, streams=[
                  StreamConfig(type="position", period_s=0.01, size=1000, phase_s=0.001)])]
    result = simulate(agents, channel=ChannelConfig(capacity_bytes_per_s=100_000.0),
                      t_end=2.0, rng=np.random.default_rng(1))
    assert drone.heard == {"uav0"}  # the background's deliveries never reach the planners
    latency = [m.t_rcv - m.t_sent for m in result.delivered if m.sender == "uav0"]
    assert max(latency) > 0.01 + 1064 / 100_000  # but its packets did delay the drone's


dask = pytest.mark.skipif(
    __import__("importlib").util.find_spec("dask") is None,
    reason="pip install -e '.[study]' (Dask distributed)")


@dask
def test_quick_fig73_the_robot_seeing_red_gets_most_frames(tmp_path: Path) -> None:
    run = subprocess.run([str(SITL), "study", "fig7.3", "--quick", "--out", str(tmp_path)],
                         capture_output=True, text=True, timeout=400)
    assert run.returncode == 0, run.stderr[-2000:]
    rows = list(csv.DictReader((tmp_path / "fig7_3_summary.csv").open()))
    fps = [float(r["fps_mean"]) for r in rows]
    assert len(fps) == 8 and fps[0] == max(fps) and fps[0] > 1.5 * np.mean(fps[3:])
    assert (tmp_path / "fig7_3.png").stat().st_size > 15_000
    assert "the robot seeing red transmits most often: holds" in run.stdout


@dask
def test_quick_fig74_application_yields_to_the_background_step(tmp_path: Path) -> None:
    run = subprocess.run([str(SITL), "study", "fig7.4", "--quick", "--out", str(tmp_path)],
                         capture_output=True, text=True, timeout=400)
    assert run.returncode == 0, run.stderr[-2000:]
    (row,) = list(csv.DictReader((tmp_path / "fig7_4.csv").open()))
    assert float(row["app_kbytes_per_s_after"]) < 0.6 * float(row["app_kbytes_per_s_before"])
    assert float(row["latency_ms_peak"]) > float(row["latency_ms_before"])
    series = list(csv.DictReader((tmp_path / "fig7_4_series.csv").open()))
    assert len(series) == 16
    bg = [float(r["background_bytes_per_s"]) for r in series]
    assert bg[2] == 0.0 and bg[-1] > 90_000.0  # off before 5.6 s, ~110 kB/s at the end
    assert (tmp_path / "fig7_4.png").stat().st_size > 15_000
