"""``uav-sitl study fig6.2``: the backlog curves on a local Dask cluster, r* next to the thesis."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("dask.distributed", reason="pip install -e '.[study]' (Dask distributed)")

from sitl.study.fig62 import crossing

SITL = Path(sys.executable).parent / "uav-sitl"


def test_crossing_interpolates_between_grid_points() -> None:
    assert crossing([0.1, 0.2, 0.3], [0.1, 0.3, 0.9], 0.6) == pytest.approx(0.25)
    assert crossing([0.1, 0.2], [0.1, 0.2], 0.5) is None


def test_quick_fig62_draws_curves_that_rise_with_rate_and_background(tmp_path: Path) -> None:
    run = subprocess.run([str(SITL), "study", "fig6.2", "--quick", "--out", str(tmp_path)],
                         capture_output=True, text=True, timeout=240)
    assert run.returncode == 0, run.stderr[-2000:]
    rows = list(csv.DictReader((tmp_path / "fig6_2.csv").open()))
    assert len(rows) == 3 * 2 * 10
    summary = list(csv.DictReader((tmp_path / "fig6_2_summary.csv").open()))
    curve = {(float(r["background_mbit"]), float(r["rate_mbit"])): float(r["backlog_mean_mbit"])
             for r in summary}
    # more background, more backlog at the same publishing rate (the figure's ordering)
    assert curve[(0.0, 0.5)] < curve[(0.25, 0.5)] < curve[(0.5, 0.5)]
    assert curve[(0.0, 0.1)] < curve[(0.0, 0.9)]
    assert (tmp_path / "fig6_2.png").stat().st_size > 20_000
    table = run.stdout.splitlines()
    r_star = [float(line.split("|")[1]) for line in table if line.strip()[:4] in
              ("0.00", "0.25", "0.50")]
    assert len(r_star) == 3 and r_star[0] > r_star[1] > r_star[2]
    assert "r* thesis" in run.stdout and " 0.90 " in run.stdout and "0.42" in run.stdout
