"""No position without a fix: GPS fix type, estimator origin and 0/0 gate every geotag."""

from __future__ import annotations

import os

os.environ.setdefault("MAVLINK20", "1")

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.mavlink import MavlinkConverter
from companion.telemetry import (
    AttitudeSample,
    EstimatorSample,
    GpsSample,
    PositionSample,
    TelemetryState,
)

T0 = 1_700_000_000.0
READY = mav.EKF_ATTITUDE | mav.EKF_POS_HORIZ_REL | mav.EKF_POS_HORIZ_ABS | mav.EKF_POS_VERT_ABS


def _wire(msg: mav.MAVLink_message) -> object:
    parsed = mav.MAVLink(None).parse_buffer(msg.pack(mav.MAVLink(None, srcSystem=1,
                                                                 srcComponent=1)))
    assert parsed is not None
    return parsed[0]


def _converter() -> MavlinkConverter:
    conv = MavlinkConverter()
    conv.convert(_wire(mav.MAVLink_heartbeat_message(
        mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 3, 3)), now=T0)
    return conv


def _state(*, fix: int = 3, lat: float = 50.06, lon: float = 19.93,
           estimator: bool | None = True, t_position: float = T0) -> TelemetryState:
    state = TelemetryState()
    state.apply(GpsSample(t=T0, fix_type=fix, satellites=10, lat_deg=lat, lon_deg=lon,
                          alt_m=250.0, eph_m=0.8))
    if estimator is not None:
        state.apply(EstimatorSample(t=T0, source="EKF_STATUS_REPORT", flags=0,
                                    position_ok=estimator))
    state.apply(PositionSample(t=t_position, lat_deg=lat, lon_deg=lon, alt_amsl_m=280.0,
                               alt_rel_m=30.0, vn_m_s=0, ve_m_s=0, vd_m_s=0, heading_deg=90.0))
    state.apply(AttitudeSample(t=T0, roll_rad=0.1, pitch_rad=0.0, yaw_rad=1.5,
                               rollspeed_rad_s=0, pitchspeed_rad_s=0, yawspeed_rad_s=0))
    return state


@pytest.mark.parametrize(("flags", "ok"), [
    (READY, True),
    (mav.EKF_ATTITUDE | mav.EKF_CONST_POS_MODE, False),  # ArduPilot after boot: no origin
    (READY | mav.EKF_UNINITIALIZED, False),
    (READY | mav.EKF_GPS_GLITCHING, False),
    (mav.EKF_ATTITUDE | mav.EKF_POS_HORIZ_REL, False),  # relative only
])
def test_ekf_status_report_says_whether_the_position_has_an_origin(flags: int, ok: bool) -> None:
    sample = _converter().convert(
        _wire(mav.MAVLink_ekf_status_report_message(flags, 0.1, 0.1, 0.1, 0.1, 0.1)), now=T0)
    assert isinstance(sample, EstimatorSample)
    assert (sample.source, sample.flags, sample.position_ok) == ("EKF_STATUS_REPORT", flags, ok)


def test_px4_estimator_status_uses_the_same_flags() -> None:
    msg = mav.MAVLink_estimator_status_message(0, mav.ESTIMATOR_POS_HORIZ_ABS
                                               | mav.ESTIMATOR_ATTITUDE,
                                               0, 0, 0, 0, 0, 0, 0, 0)
    sample = _converter().convert(_wire(msg), now=T0)
    assert isinstance(sample, EstimatorSample)
    assert (sample.source, sample.position_ok) == ("ESTIMATOR_STATUS", True)


@pytest.mark.parametrize(("flags", "ok"), [
    (1023, True),  # PX4 SIH on the ground with GNSS: CONST_POS_MODE is its "at rest"
    (895, True),  # PX4 SIH in the air
    (229, False),  # PX4 SIH before the GNSS is fused
    (1023 & ~mav.ESTIMATOR_PRED_POS_HORIZ_ABS, False),  # at rest on a fake position, no GNSS
    (1023 | mav.ESTIMATOR_GPS_GLITCH, False),
])
def test_px4_at_rest_with_gnss_has_a_position(flags: int, ok: bool) -> None:
    """Measured on PX4 SIH (docs/sitl.md): ekf2 sets CONST_POS_MODE whenever the vehicle is at
    rest, so a PX4 drone on the ground reported 1023; taking the bit for "no GPS" (as it
    means on ArduPilot) kept its position off the dashboard until it took off."""
    msg = mav.MAVLink_estimator_status_message(0, flags, 0, 0, 0, 0, 0, 0, 0, 0)
    sample = _converter().convert(_wire(msg), now=T0)
    assert isinstance(sample, EstimatorSample)
    assert sample.position_ok is ok


def test_a_valid_fix_geotags_with_the_pose_age() -> None:
    snap = _state(t_position=T0 - 0.4).snapshot()
    assert snap.position_problem is None and snap.has_pose
    assert snap.geotag(at=T0) == {
        "lat_deg": 50.06, "lon_deg": 19.93, "alt_rel_m": 30.0, "alt_amsl_m": 280.0,
        "roll_rad": 0.1, "pitch_rad": 0.0, "yaw_rad": 1.5, "heading_deg": 90.0,
        "pose_age_s": 0.4,
    }


@pytest.mark.parametrize(("kw", "problem"), [
    ({"fix": 1}, "no 3-D GPS fix (fix_type 1)"),
    ({"fix": 2}, "no 3-D GPS fix (fix_type 2)"),
    ({"estimator": False}, "the estimator has no absolute position (no origin yet)"),
    ({"lat": 0.0, "lon": 0.0}, "position is 0/0 (no origin)"),
])
def test_no_fix_no_origin_or_null_island_give_no_position(kw: dict[str, object],
                                                          problem: str) -> None:
    snap = _state(**kw).snapshot()  # type: ignore[arg-type]
    assert snap.position_problem == problem
    assert not snap.has_pose
    assert snap.geotag(at=T0) == {"roll_rad": 0.1, "pitch_rad": 0.0, "yaw_rad": 1.5,
                                  "heading_deg": 90.0, "position": "none"}


def test_a_stack_without_estimator_reports_is_judged_by_gps_alone() -> None:
    assert _state(estimator=None).snapshot().position_problem is None
    assert TelemetryState().snapshot().position_problem == "no position received"
    state = TelemetryState()
    state.apply(PositionSample(t=T0, lat_deg=50.0, lon_deg=19.0, alt_amsl_m=1, alt_rel_m=1,
                               vn_m_s=0, ve_m_s=0, vd_m_s=0, heading_deg=None))
    assert state.snapshot().position_problem == "no GPS report received"


def test_the_fix_is_lost_again() -> None:
    state = _state()
    state.apply(GpsSample(t=T0 + 1, fix_type=0, satellites=0, lat_deg=0.0, lon_deg=0.0,
                          alt_m=0.0, eph_m=None))
    assert state.snapshot().position_problem == "no 3-D GPS fix (fix_type 0)"


def _gps_position(state: TelemetryState, t: float) -> None:
    state.apply(GpsSample(t=t, fix_type=3, satellites=10, lat_deg=50.06, lon_deg=19.93,
                          alt_m=250.0, eph_m=0.8))
    state.apply(PositionSample(t=t, lat_deg=50.06, lon_deg=19.93, alt_amsl_m=280.0,
                               alt_rel_m=30.0, vn_m_s=0, ve_m_s=0, vd_m_s=0, heading_deg=90.0))


def test_a_new_link_waits_for_the_estimator_before_trusting_the_gps() -> None:
    """ArduCopter streams a 3D fix and its position before the first EKF_STATUS_REPORT of a
    connection arrives (and 33 s before the EKF uses the GPS): in between, the position was
    taken as usable. It waits for the estimator, up to ESTIMATOR_GRACE_S of GPS reports."""
    from companion.telemetry import ESTIMATOR_GRACE_S, LinkStateSample

    state = TelemetryState()
    state.apply(LinkStateSample(t=T0, connected=True, reason="heartbeat from system 1"))
    _gps_position(state, T0 + 0.2)
    assert state.snapshot().position_problem == "waiting for the estimator's first report"
    state.apply(EstimatorSample(t=T0 + 0.5, source="EKF_STATUS_REPORT", flags=0,
                                position_ok=False))
    assert state.snapshot().position_problem == \
        "the estimator has no absolute position (no origin yet)"
    state.apply(EstimatorSample(t=T0 + 0.9, source="EKF_STATUS_REPORT", flags=READY,
                                position_ok=True))
    assert state.snapshot().position_problem is None

    silent = TelemetryState()  # a stack that sends no estimator report at all
    silent.apply(LinkStateSample(t=T0, connected=True, reason="heartbeat from system 1"))
    _gps_position(silent, T0 + ESTIMATOR_GRACE_S - 0.1)
    assert silent.snapshot().position_problem == "waiting for the estimator's first report"
    _gps_position(silent, T0 + ESTIMATOR_GRACE_S)
    assert silent.snapshot().position_problem is None


def test_a_reconnect_forgets_the_last_connections_fix_and_estimator() -> None:
    """After a reboot the autopilot has neither: the previous connection's 3D fix and EKF
    origin must not vouch for the first positions of the new one."""
    from companion.telemetry import LinkStateSample

    state = TelemetryState()
    state.apply(LinkStateSample(t=T0, connected=True, reason="heartbeat from system 1"))
    state.apply(EstimatorSample(t=T0 + 0.1, source="EKF_STATUS_REPORT", flags=READY,
                                position_ok=True))
    _gps_position(state, T0 + 0.2)
    assert state.snapshot().position_problem is None
    state.apply(LinkStateSample(t=T0 + 10, connected=False, reason="no heartbeat for 3 s"))
    state.apply(LinkStateSample(t=T0 + 30, connected=True, reason="heartbeat from system 1"))
    snap = state.snapshot()
    assert snap.position_problem == "no GPS report received"
    assert snap.lat_deg == 50.06  # the last known position stays (not as a usable one)
    _gps_position(state, T0 + 30.5)
    assert state.snapshot().position_problem == "waiting for the estimator's first report"
