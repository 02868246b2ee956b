"""The built-in vehicle passes the client checks a real ArduCopter and a real PX4 SIH pass
(``autopilot_checks``): heartbeat, streams, first fix and home, parameters, mission up/down,
mode confirmed by HEARTBEAT, arm, takeoff, climb, mission progress, landing.

Run against a real SITL too: ``UAV_TEST_MAVLINK_URL=udpin:0.0.0.0:14550 pytest
tests/sitl/test_sitl_vehicle_conformance.py`` (docs/companion.md, "Testing against a real
autopilot")."""

from __future__ import annotations

import os

import pytest

from tests.autopilot_checks import run_all_checks


@pytest.mark.timeout(120)
@pytest.mark.parametrize("flavour", ["ardupilot", "px4"])
def test_builtin_vehicle_passes_the_real_autopilot_checks(vehicle_process, flavour):
    # A 20 s boot without a fix (simulated; 2 s wall at 10x) keeps the wait for it in play.
    # PX4 disarms after COM_DISARM_PRFLT (10 s) armed on the ground: 1 s of wall time at 10x,
    # less than the checks' arm, HEARTBEAT (1 Hz), home read, takeoff take; 100 simulated
    # seconds give the 10 wall seconds a client of a real PX4 has.
    extra = ["--param", "COM_DISARM_PRFLT=100"] if flavour == "px4" else []
    vehicle = vehicle_process("--flavour", flavour, "--speedup", "10", "--first-fix", "20",
                              *extra)
    ap = run_all_checks(f"udpout:127.0.0.1:{vehicle.port}")
    assert ap.ardupilot == (flavour == "ardupilot")
    assert ap.home is not None
    assert ap.home[:2] == pytest.approx((vehicle.records[0]["home"][0],
                                         vehicle.records[0]["home"][1]), abs=1e-6)


@pytest.mark.timeout(600)
@pytest.mark.skipif(not os.environ.get("UAV_TEST_MAVLINK_URL"),
                    reason="set UAV_TEST_MAVLINK_URL (e.g. udpin:0.0.0.0:14550) to run the same "
                           "checks against a real ArduPilot/PX4 SITL; see docs/companion.md")
def test_real_autopilot_passes_the_checks():
    # The checks are a GCS: they fly on the GCS link when one is named. ArduPilot SITL opens
    # its second serial port (the companion's) only once a client is on the first.
    run_all_checks(os.environ.get("UAV_TEST_MAVLINK_GCS_URL") or os.environ["UAV_TEST_MAVLINK_URL"])
