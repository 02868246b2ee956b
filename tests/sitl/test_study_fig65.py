"""``uav-sitl study fig6.5``: ξ smoothness and step response, adaptive (both modes) vs AIMD."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("dask.distributed", reason="pip install -e '.[study]' (Dask distributed)")

SITL = Path(sys.executable).parent / "uav-sitl"


def test_quick_fig65_writes_the_numbers_and_the_plot(tmp_path: Path) -> None:
    run = subprocess.run([str(SITL), "study", "fig6.5", "--quick", "--out", str(tmp_path)],
                         capture_output=True, text=True, timeout=400)
    assert run.returncode == 0, run.stderr[-2000:]
    rows = {r["constraint"]: r for r in csv.DictReader((tmp_path / "fig6_5_summary.csv").open())}
    assert set(rows) == {"adaptive", "adaptive-weighted", "adaptive-smooth", "aimd"}
    for r in rows.values():
        assert float(r["p95_queueing_ms_mean"]) < 100.0 and float(r["loss_mean"]) == 0.0
    for smooth in ("adaptive-weighted", "adaptive-smooth"):  # smoother than the thesis' SGD
        assert (float(rows[smooth]["cv_second_half_mean"])
                < float(rows["adaptive"]["cv_second_half_mean"]))
    assert (tmp_path / "fig6_5.png").stat().st_size > 20_000
    assert "targets: CV <= AIMD's" in run.stdout
