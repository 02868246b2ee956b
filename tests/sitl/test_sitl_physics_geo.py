"""The pure physics step and the geodetic helpers: formulas and properties."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sitl.geo import Enu, GeoPoint, enu_from_geo, geo_from_enu
from sitl.vehicle.physics import Airframe, Setpoint, VehicleState, gps_reading, step

DT = 0.02


def _fly(state: VehicleState, seconds: float) -> VehicleState:
    for _ in range(round(seconds / DT)):
        state = step(state, DT)
    return state


def _airborne(**kw) -> VehicleState:
    return VehicleState(position_ned_m=(0.0, 0.0, -20.0), armed=True, on_ground=False, **kw)


finite = st.floats(min_value=-200, max_value=200, allow_nan=False)


@settings(max_examples=30, deadline=None)
@given(n=finite, e=finite, d=st.floats(min_value=-80, max_value=0), speed=st.none() | st.floats(
    min_value=0.5, max_value=20))
def test_speed_and_acceleration_stay_within_the_airframe_limits(n, e, d, speed):
    af = Airframe()
    state = _airborne(setpoint=Setpoint(position_ned_m=(n, e, d), speed_m_s=speed))
    for _ in range(300):
        new = step(state, DT)
        v = new.velocity_ned_m_s
        assert math.hypot(v[0], v[1]) <= af.max_speed_h_m_s + 1e-9
        assert -af.max_speed_up_m_s - 1e-9 <= v[2] <= af.max_speed_down_m_s + 1e-9 or new.on_ground
        dv = math.hypot(v[0] - state.velocity_ned_m_s[0], v[1] - state.velocity_ned_m_s[1])
        drag = af.drag_1_s * math.hypot(*state.velocity_ned_m_s[:2])
        assert dv <= (af.max_accel_m_s2 + drag) * DT + 1e-9
        assert new.position_ned_m[2] <= 0.0  # never below the ground
        state = new


def test_reaches_a_position_setpoint_and_stops_there():
    state = _airborne(setpoint=Setpoint(position_ned_m=(60.0, -40.0, -30.0)))
    state = _fly(state, 40.0)
    assert state.position_ned_m == pytest.approx((60.0, -40.0, -30.0), abs=0.05)
    assert math.hypot(*state.velocity_ned_m_s) < 0.05


def test_hover_energy_is_hover_power_times_time():
    state = _airborne(setpoint=Setpoint(position_ned_m=(0.0, 0.0, -20.0)))
    state = _fly(state, 60.0)
    af = state.airframe
    assert state.energy_used_wh == pytest.approx(af.hover_power_w * 60.0 / 3600.0, rel=1e-9)
    assert state.battery_remaining == pytest.approx(1 - 3.0 / af.battery_capacity_wh)


def test_disarmed_on_the_ground_nothing_moves_or_drains():
    state = VehicleState(setpoint=Setpoint(position_ned_m=(10.0, 0.0, -10.0)))
    after = _fly(state, 5.0)
    assert after.position_ned_m == (0.0, 0.0, 0.0)
    assert after.energy_used_wh == 0.0
    assert after.t_s == pytest.approx(5.0)


def test_wind_tilts_the_vehicle_into_it_and_costs_power():
    hold = Setpoint(position_ned_m=(0.0, 0.0, -20.0))
    calm = _fly(_airborne(setpoint=hold), 20.0)
    windy = _fly(_airborne(setpoint=hold, wind_ned_m_s=(-6.0, 0.0, 0.0)), 20.0)  # from north
    assert calm.pitch_rad == pytest.approx(0.0, abs=1e-9)
    assert windy.pitch_rad < -0.05  # nose down = leaning north into the wind
    assert windy.power_w > calm.power_w
    # A small downwind offset remains (the controller cancels 80% of the drag at once).
    assert -1.0 < windy.position_ned_m[0] < -0.01


def test_gps_noise_has_the_requested_spread():
    rng = np.random.default_rng(42)
    state = _airborne()
    fixes = np.array([gps_reading(state, rng, sigma_h_m=0.5).position_ned_m for _ in range(4000)])
    assert fixes[:, 0].std() == pytest.approx(0.5, rel=0.05)
    assert fixes[:, 0].mean() == pytest.approx(0.0, abs=0.03)
    again = gps_reading(state, np.random.default_rng(42), sigma_h_m=0.5)
    assert again.position_ned_m == tuple(fixes[0])


def test_step_rejects_a_non_positive_dt():
    with pytest.raises(ValueError, match="dt_s"):
        step(VehicleState(), 0.0)


def test_airframe_validates_limits():
    with pytest.raises(ValueError, match="max_speed_h_m_s"):
        replace(Airframe(), max_speed_h_m_s=0.0)


# ---------------------------------------------------------------------------- geodesy

def test_enu_of_known_offsets_at_the_equator():
    origin = GeoPoint(lat_deg=0.0, lon_deg=0.0, alt_m=0.0)
    east = enu_from_geo(GeoPoint(lat_deg=0.0, lon_deg=0.001), origin)
    north = enu_from_geo(GeoPoint(lat_deg=0.001, lon_deg=0.0), origin)
    # WGS84: 111319.49 m per degree of longitude, 110574.28 m per degree of latitude there.
    assert east.east_m == pytest.approx(111.31949, abs=1e-3)
    assert north.north_m == pytest.approx(110.57428, abs=1e-3)
    assert abs(east.north_m) < 1e-6 and abs(north.east_m) < 1e-6


@settings(max_examples=60, deadline=None)
@given(lat=st.floats(-85, 85), lon=st.floats(-179, 179), alt=st.floats(-100, 5000),
       e=st.floats(-20_000, 20_000), n=st.floats(-20_000, 20_000), u=st.floats(-500, 3000))
def test_geo_enu_round_trip(lat, lon, alt, e, n, u):
    origin = GeoPoint(lat_deg=lat, lon_deg=lon, alt_m=alt)
    back = enu_from_geo(geo_from_enu(Enu(east_m=e, north_m=n, up_m=u), origin), origin)
    assert (back.east_m, back.north_m, back.up_m) == pytest.approx((e, n, u), abs=1e-4)


def test_geo_point_validates():
    with pytest.raises(ValueError, match="lat_deg"):
        GeoPoint(lat_deg=91.0, lon_deg=0.0)
