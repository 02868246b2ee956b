"""``uav-sitl study fig6.1``: jittered sends on the FIFO link; the command on a Dask cluster."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("dask.distributed", reason="pip install -e '.[study]' (Dask distributed)")

from sitl.study.fig61 import MBIT, jittered_link

SITL = Path(sys.executable).parent / "uav-sitl"


def test_even_sends_below_capacity_see_only_service_and_propagation() -> None:
    rate, latency, lost = jittered_link(0.5 * MBIT, 0.0, duration_s=10.0,
                                        rng=np.random.default_rng(1))
    assert lost == 0
    assert latency == pytest.approx(1200 / MBIT + 0.02)  # 9.6 ms service + 20 ms propagation
    assert rate == pytest.approx(0.5 * MBIT, rel=0.01)


def test_overload_is_capped_at_capacity_and_the_queue_drops() -> None:
    rate, latency, lost = jittered_link(1.5 * MBIT, 0.001, duration_s=10.0,
                                        rng=np.random.default_rng(1))
    assert rate == pytest.approx(MBIT, rel=0.01) and lost > 0
    assert latency > 0.4  # a full 60 kB queue is 0.48 s of service


def test_quick_fig61_latency_grows_earlier_with_more_jitter(tmp_path: Path) -> None:
    run = subprocess.run([str(SITL), "study", "fig6.1", "--quick", "--out", str(tmp_path)],
                         capture_output=True, text=True, timeout=240)
    assert run.returncode == 0, run.stderr[-2000:]
    rows = list(csv.DictReader((tmp_path / "fig6_1_summary.csv").open()))
    lat = {(float(r["sigma_s"]), float(r["rate_mbit"])): float(r["latency_mean_ms"])
           for r in rows}
    assert lat[(0.001, 0.7)] < lat[(0.01, 0.7)] < lat[(0.1, 0.7)]
    assert lat[(0.001, 0.7)] == pytest.approx(29.6, abs=0.2)
    assert (tmp_path / "fig6_1.png").stat().st_size > 20_000
    assert "σ = 0.1" in run.stdout and "thesis: no numbers stated" in run.stdout
