"""StreamWatch: a reboot seen in ``time_boot_ms``, and streams that stopped while the
autopilot's HEARTBEAT goes on (companion/mavlink_watch.py)."""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as m

from companion.mavlink_watch import StreamWatch, stalled_s


def _attitude(boot_ms: int) -> m.MAVLink_attitude_message:
    return m.MAVLink_attitude_message(boot_ms, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


def test_time_since_boot_going_back_is_a_reboot() -> None:
    watch = StreamWatch(silence_s=3.0)
    assert watch.rebooted(_attitude(600_000), 0.0) is None
    assert watch.rebooted(_attitude(599_500), 0.1) is None  # within the tolerance
    assert watch.rebooted(_attitude(600_200), 0.2) is None
    assert watch.rebooted(_attitude(1_800), 2.5) == (
        "autopilot rebooted (time since boot went back from 600.2 s to 1.8 s)")
    assert watch.rebooted(_attitude(2_000), 2.6) is None  # the new boot's clock goes on
    heartbeat = m.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3)
    assert watch.rebooted(heartbeat, 2.7) is None  # no clock in it
    pressure = m.MAVLink_scaled_pressure_message(0, 1013.0, 0.0, 2000)
    assert watch.rebooted(pressure, 2.8) is None  # a clock not trusted (0: unfilled)
    assert watch.rebooted(_attitude(2_100), 2.9) is None


def test_silence_counts_only_wanted_streams_and_restarts_at_each_request() -> None:
    watch = StreamWatch(silence_s=3.0)
    assert not watch.silent(100.0)  # nothing asked yet
    watch.asked(["ATTITUDE", "RC_CHANNELS"], [10.0, 0.0], 10.0)
    assert watch.wanted == {"ATTITUDE"}  # a stream turned off is not awaited
    assert not watch.silent(12.9)
    assert watch.silent(13.1)
    watch.told = True
    watch.rebooted(_attitude(5_000), 13.2)
    assert not watch.silent(16.1) and watch.told is False  # it flows again
    rc = m.MAVLink_rc_channels_message(5_100, 8, *([1500] * 18), 255)
    watch.rebooted(rc, 20.0)
    assert watch.silent(20.0)  # not a wanted one: the silence goes on
    watch.asked(["ATTITUDE"], [10.0], 20.0)
    assert not watch.silent(22.0)


def test_nothing_wanted_is_never_silent() -> None:
    watch = StreamWatch(silence_s=3.0)
    watch.asked(["HIGHRES_IMU"], [0.0], 0.0)
    assert not watch.silent(1e6)


def test_a_gap_between_receives_beyond_the_wait_is_a_stall() -> None:
    # pymavlink waits up to 1.5 x the receive timeout (0.5 s: 0.75 s), then 1 s of slack
    assert stalled_s(None, 100.0, 0.5) == 0.0  # nothing received yet
    assert stalled_s(100.0, 100.75, 0.5) == 0.0
    assert stalled_s(100.0, 101.75, 0.5) == 0.0  # slack: a slow round, not a stall
    assert stalled_s(100.0, 101.76, 0.5) == pytest.approx(1.76)
    assert stalled_s(100.0, 109.75, 0.5) == pytest.approx(9.75)  # the whole gap
    assert stalled_s(100.0, 99.0, 0.5) == -1.0  # the clock stepped back
