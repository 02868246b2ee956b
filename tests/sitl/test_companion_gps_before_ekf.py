"""The companion against the built-in ArduPilot vehicle in the window a real ArduCopter has
after boot: the GPS has a 3D fix and GLOBAL_POSITION_INT carries its position, but the EKF has
no origin yet (CONST_POS_MODE). Measured on ArduCopter 4.5 SITL: fix 8.7 s, EKF using the GPS
41.5 s after start. The companion must not use that position (no geotag, nothing sent)."""

from __future__ import annotations

import dataclasses
import threading
import time
from pathlib import Path

from companion.config import load_config
from companion.mavlink import MavlinkReader
from companion.telemetry import Sample, TelemetryState


def test_no_position_while_the_ekf_has_no_origin(vehicle_process, tmp_path: Path) -> None:
    # 5x: the GPS fix at 0.2 x 30 = 6 simulated s (1.2 s wall), the EKF at 30 s (6 s wall).
    # At 10x the window between them was 2.4 s wall: on a loaded CI machine the estimator's
    # first report on this link could come only after the EKF had its origin.
    vehicle = vehicle_process("--flavour", "ardupilot", "--speedup", "5", "--first-fix", "30")
    config_file = tmp_path / "companion.toml"
    # a short stream table, as the shipped example had: no EKF_STATUS_REPORT listed
    config_file.write_text('[drone]\nid = "d1"\n[mavlink.stream_rates_hz]\n'
                           'GLOBAL_POSITION_INT = 5.0\nGPS_RAW_INT = 5.0\n')
    settings = dataclasses.replace(load_config(config_file).mavlink,
                                   url=f"udpout:127.0.0.1:{vehicle.port}")
    state, lock = TelemetryState(), threading.Lock()
    problems: list[tuple[int | None, str | None]] = []

    def post(sample: Sample) -> None:
        with lock:
            state.apply(sample)
            snap = state.snapshot()
            if snap.lat_deg:  # a position (not 0/0) came
                problems.append((snap.gps_fix_type, snap.position_problem))

    reader = MavlinkReader(settings, clock=time.time, post=post)
    reader.start()
    try:
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline:
            with lock:
                if problems and problems[-1][1] is None:
                    break
            time.sleep(0.05)
    finally:
        reader.stop()
        reader.join(5)
    with lock:
        seen = list(problems)
    assert seen and seen[-1][1] is None, f"the position never became usable: {seen[-3:]}"
    # before the EKF: positions with a 3D GPS fix, each refused because of the estimator
    early = [p for p in seen if p[1] is not None]
    assert early, "no GPS position before the EKF had an origin (the vehicle's boot changed?)"
    with_fix = [p for fix, p in early if fix is not None and fix >= 3]
    assert with_fix, f"no GPS position refused for want of an EKF origin: {seen[:4]}"
    # refused for the estimator: it says no origin, or has not spoken yet on this link
    no_origin = "the estimator has no absolute position (no origin yet)"
    assert no_origin in with_fix, seen[:6]
    assert set(with_fix) <= {no_origin, "waiting for the estimator's first report"}, seen[:6]
