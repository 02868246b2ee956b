"""A station without ``shared_medium`` tells when a drone's status never arrives
(ground_station/medium_hint.py).

Seen on a netns fleet by hand: drones on ``peers.medium`` with ``builtin:peer_sharing``
(status and position sent once, on the medium), the station without ``shared_medium``: the
dashboard showed each drone's images but mode "–" and no peers, and the log said nothing.
"""

from __future__ import annotations

import logging

import pytest

from ground_station.fleet import FleetView
from ground_station.medium_hint import StatusUnheard
from utility_specs.message import Message


def message(sender: str, type_: str, t: float) -> Message:
    return Message(sender=sender, seq=int(t), type=type_, t_gen=t, size=100, data={})


def test_a_drone_without_status_is_told_once(caplog: pytest.LogCaptureFixture) -> None:
    fleet = FleetView(high_utility=None, link_lost_s=1000.0)
    fleet.status_unheard = StatusUnheard(after_s=30.0)
    for t in range(0, 41):
        fleet.on_message(message("d1", "image", 1000.0 + t), now=1000.0 + t)
        fleet.on_message(message("d2", "image" if t % 2 else "status", 1000.0 + t),
                         now=1000.0 + t)
        fleet.tick(now=1000.0 + t)
    told = [a for a in fleet.alerts if a.kind == "config"]
    assert [(a.drone, a.level) for a in told] == [("d1", "warning")]
    assert told[0].text.startswith("30 s of messages from d1 and no status: ")
    assert "set shared_medium to the drones' peers.medium" in told[0].text
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and "d1" in warnings[0].getMessage()


def test_a_station_on_another_medium_says_which_it_hears() -> None:
    """A station with a shared_medium other than the drones' (seen: broadcast port 14700
    while the drones used multicast) showed the same dashboard and said nothing either."""
    watch = StatusUnheard(medium="broadcast:10.77.0.255:14700", after_s=30.0)
    watch.on_message("d1", "image", 0.0)
    [(drone, text)] = watch.check(31.0)
    assert drone == "d1"
    assert "this station's is 'broadcast:10.77.0.255:14700': not the one the drone sends on?" \
        in text


def test_every_station_looks(tmp_path: object) -> None:
    from pathlib import Path

    from ground_station.app import create_app
    from ground_station.config import GroundConfig
    from ground_station.keys import FLEET
    from tests.keys import TEST_COMMAND_KEY, TEST_FLEET_KEY

    assert isinstance(tmp_path, Path)
    base = GroundConfig(fleet_key=TEST_FLEET_KEY, command_key=TEST_COMMAND_KEY,
                        data_dir=tmp_path / "gs", udp_port=0)
    without = create_app(base, token="t" * 24)
    assert without[FLEET].status_unheard is not None
    on_medium = create_app(base.with_overrides(
        shared_medium="broadcast:127.255.255.255:14799", data_dir=tmp_path / "gs2"),
        token="t" * 24)
    assert on_medium[FLEET].status_unheard is not None
    assert on_medium[FLEET].status_unheard.medium == "broadcast:127.255.255.255:14799"
