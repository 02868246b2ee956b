"""The built-in vehicle's SYSTEM_TIME as a real autopilot's: the companion checks its own
clock against it (companion.clock_check), so it must be UTC once there is GPS time and say
"unknown" (0) before, as ArduCopter 4.5 SITL does (measured: 0 until the GPS has the time)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sitl.vehicle.flavour import ARDUPILOT, PX4

BOOT_UNIX_S = 1_796_000_000.0


@pytest.mark.parametrize("flavour", ["ardupilot", "px4"])
def test_system_time_is_unknown_before_the_fix_on_ardupilot_and_utc_after(
        make_gcs: Callable[..., Any], flavour: str) -> None:
    gcs = make_gcs(flavour={"ardupilot": ARDUPILOT, "px4": PX4}[flavour], first_fix_s=20.0,
                   boot_unix_s=BOOT_UNIX_S)  # ArduPilot's GPS fix at 0.2 of it: 4 s
    gcs.run_until(2.0)
    gcs.command(mavlink.MAV_CMD_REQUEST_MESSAGE, 2)
    early = gcs.of_type("SYSTEM_TIME")[-1]
    assert early.time_unix_usec == (0 if flavour == "ardupilot"
                                    else pytest.approx((BOOT_UNIX_S + 2.0) * 1e6, abs=2e5))
    gcs.run_until(22.0)
    gcs.command(mavlink.MAV_CMD_REQUEST_MESSAGE, 2)
    late = gcs.of_type("SYSTEM_TIME")[-1]
    assert late.time_unix_usec == pytest.approx((BOOT_UNIX_S + 22.0) * 1e6, abs=2e5)
