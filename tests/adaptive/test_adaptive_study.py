"""``uav-sitl study adaptive-vs-aimd``: runs, writes CSV and PNG, and the model is sane."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from sitl.study.adaptive import (
    ObservedConstant,
    SimLink,
    main,
    rfc8867_5_1,
    simulate,
    steps,
)


def test_study_writes_csv_and_png(tmp_path: Path) -> None:
    assert main(["--out", str(tmp_path), "--time-scale", "0.3"]) == 0
    for name in ("fig6_5.png", "rfc8867_model.png"):
        assert (tmp_path / name).stat().st_size > 10_000
    with (tmp_path / "fig6_5_adaptive.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 500  # one row per 0.2 s report over 100 s
    assert {"t_s", "xi_bytes_per_s", "goodput_bytes_per_s", "background_bytes_per_s"} <= set(
        rows[0])
    for stem in ("rfc8867_model_adaptive", "rfc8867_model_aimd", "rfc8867_model_fixed"):
        assert (tmp_path / f"{stem}.csv").exists()


def test_fifo_link_model_is_work_conserving_and_bounded() -> None:
    """Open loop at 1.5x capacity: delivered rate = capacity, queue delay ≤ limit / rate."""
    link = SimLink(capacity_bytes_per_s=steps((0.0, 100_000.0)), queue_limit_bytes=20_000,
                   propagation_s=0.02)
    trace = simulate(ObservedConstant(limit_bytes_per_s=150_000.0), duration_s=30.0,
                     rng=np.random.default_rng(0), link=link,
                     demand_bytes_per_s=steps((0.0, 150_000.0)))
    assert abs(trace.delivered_rate(5.0, 30.0) - 100_000.0) < 2_500.0
    latency = [r - s for s, r, _ in trace.sent if r is not None]
    assert max(latency) <= 0.02 + 20_000 / 100_000.0 + 1200 / 100_000.0 + 1e-9
    assert min(latency) >= 0.02 + 1200 / 100_000.0 - 1e-9
    assert any(r is None for _, r, _ in trace.sent)  # tail drops happened


def test_rfc8867_schedule_is_the_rfc_one() -> None:
    s = rfc8867_5_1()
    assert s.rate_bit_per_s == ((0.0, 1e6), (40.0, 2.5e6), (60.0, 0.6e6), (80.0, 1e6))
    assert s.duration_s == 100.0
    assert rfc8867_5_1(time_scale=0.5).step_times == [0.0, 20.0, 30.0, 40.0]
    # payload capacity left: 1 Mbit/s of 1242-byte frames carries 1200-byte payloads
    assert s.left_bytes_per_s(0.0) == 1e6 / 8 * 1200 / 1242
