"""``uav-sitl study fig6.3`` (figs. 6.3/6.4): the α sweep of the adaptive constraint."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("dask.distributed", reason="pip install -e '.[study]' (Dask distributed)")

SITL = Path(sys.executable).parent / "uav-sitl"


def test_quick_alpha_sweep_trades_rate_for_loss_and_latency(tmp_path: Path) -> None:
    run = subprocess.run([str(SITL), "study", "fig6.4", "--quick", "--out", str(tmp_path)],
                         capture_output=True, text=True, timeout=400)
    assert run.returncode == 0, run.stderr[-2000:]
    rows = list(csv.DictReader((tmp_path / "fig6_3_summary.csv").open()))
    adaptive = sorted((float(r["alpha_or_rate_mbit"]), r) for r in rows
                      if r["mode"] == "adaptive")
    assert [a for a, _ in adaptive] == [0.25, 1.0, 2.0]
    publishing = [float(r["publishing_mbit_mean"]) for _, r in adaptive]
    latency = [float(r["latency_ms_mean"]) for _, r in adaptive]
    assert publishing == sorted(publishing) and latency == sorted(latency)
    # the smallest α keeps the link uncongested: nothing lost; the largest overloads it
    assert float(adaptive[0][1]["loss_mean"]) == 0.0 < float(adaptive[-1][1]["loss_mean"])
    fixed = [r for r in rows if r["mode"] == "fixed"]
    assert len(fixed) == 4
    for r in fixed:  # what arrives never exceeds what was sent
        assert float(r["reception_mbit_mean"]) <= float(r["publishing_mbit_mean"]) + 1e-9
    for name in ("fig6_3.png", "fig6_4.png"):
        assert (tmp_path / name).stat().st_size > 15_000
    assert "higher α -> higher publishing rate: holds" in run.stdout
    assert "thesis: no numbers stated" in run.stdout
