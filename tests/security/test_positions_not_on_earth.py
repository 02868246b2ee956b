"""A position that is not on Earth is no position (docs/security.md, 2026-11-24).

GLOBAL_POSITION_INT carries latitude and longitude as int32 1e-7 degrees: a broken or hostile
autopilot can report 214.7 deg. The companion sent it as the drone's position, the station
drew it and, as the first position it saw, took it as its map's origin (every real drone then
hundreds of kilometres away), and the export listed it as a good geotag.
"""

from __future__ import annotations

import pytest

from companion.telemetry import (
    EstimatorSample,
    GpsSample,
    PositionSample,
    TelemetryState,
)
from ground_station.fleet import FleetView
from ground_station.storage_records import pose_quality

INT32_MAX_DEG = (2**31 - 1) * 1e-7
BAD = [(INT32_MAX_DEG, 8.5), (47.4, INT32_MAX_DEG), (-90.5, 8.5), (47.4, -180.01),
       (-INT32_MAX_DEG, -INT32_MAX_DEG)]


@pytest.mark.parametrize(("lat", "lon"), BAD)
def test_the_companion_does_not_take_it_for_a_position(lat: float, lon: float) -> None:
    state = TelemetryState()
    state.apply(GpsSample(t=1.0, fix_type=3, satellites=12, lat_deg=lat, lon_deg=lon,
                          alt_m=500.0, eph_m=1.0))
    state.apply(EstimatorSample(t=1.0, source="EKF_STATUS_REPORT", flags=0, position_ok=True))
    state.apply(PositionSample(t=1.0, lat_deg=lat, lon_deg=lon, alt_amsl_m=500.0,
                               alt_rel_m=20.0, vn_m_s=0.0, ve_m_s=0.0, vd_m_s=0.0,
                               heading_deg=None))
    snap = state.snapshot()
    assert snap.position_problem is not None and "not on Earth" in snap.position_problem
    tag = snap.geotag(at=1.0)
    assert tag.get("position") == "none" and "lat_deg" not in tag


def test_a_real_position_still_is_one() -> None:
    state = TelemetryState()
    state.apply(GpsSample(t=1.0, fix_type=3, satellites=12, lat_deg=-90.0, lon_deg=180.0,
                          alt_m=2800.0, eph_m=1.0))
    state.apply(EstimatorSample(t=1.0, source="EKF_STATUS_REPORT", flags=0, position_ok=True))
    state.apply(PositionSample(t=1.0, lat_deg=-90.0, lon_deg=180.0, alt_amsl_m=2800.0,
                               alt_rel_m=20.0, vn_m_s=0.0, ve_m_s=0.0, vd_m_s=0.0,
                               heading_deg=None))
    assert state.snapshot().position_problem is None


@pytest.mark.parametrize(("lat", "lon"), BAD)
def test_the_station_neither_draws_it_nor_takes_it_as_the_origin(lat: float,
                                                                 lon: float) -> None:
    view = FleetView(high_utility=None, link_lost_s=5.0)
    liar = view.heard("liar", now=100.0)
    view.apply_data(liar, {"lat_deg": lat, "lon_deg": lon}, now=100.0)
    assert view.drone_json(liar, now=100.0)["lat_deg"] is None
    honest = view.heard("honest", now=101.0)
    view.apply_data(honest, {"lat_deg": 47.4, "lon_deg": 8.5}, now=101.0)
    tile = view.drone_json(honest, now=101.0)
    assert (tile["x_m"], tile["y_m"]) == (0.0, 0.0)  # the honest drone is the origin
    assert pose_quality({"lat_deg": lat, "lon_deg": lon}) == (None, "none")
