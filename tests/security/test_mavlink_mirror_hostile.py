"""The station's MAVLink fleet mirror (``mavlink_listen``) against hostile clients
(docs/security.md, 2026-11-24). Anyone who can reach its UDP port can send to it, without a
key; before these fixes one such sender could

* keep a GCS from ever registering: one parser was shared by every client, so a 10-byte torn
  frame from anywhere swallowed the GCS's next datagram as its payload (10 of 10 lost);
* take the GCS's place: eight HEARTBEATs from new addresses pushed out the oldest client,
  the operator's GCS still sending among them; a client that left stayed a destination;
* grow the counters without bound: one ``ignored_UNKNOWN_<id>`` key per 24-bit message id
  (about 2800 keys from 60 000 fuzzed datagrams).
"""

from __future__ import annotations

import os
import random
from typing import Any

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mav

from ground_station.mavlink_mirror import CLIENT_TIMEOUT_S, MavlinkMirror
from ground_station.mavlink_out import MavlinkOut

GCS = ("10.0.0.5", 14550)
_gcs = mav.MAVLink(None, srcSystem=255, srcComponent=190)
HEARTBEAT = _gcs.heartbeat_encode(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0,
                                  mav.MAV_STATE_ACTIVE).pack(_gcs)
TORN = bytes([0xFD, 255, 0, 0, 0, 1, 1, 0, 0, 0])  # a MAVLink 2 header promising 255 bytes


def test_a_torn_frame_from_anyone_does_not_swallow_the_next_client_datagram() -> None:
    mirror = MavlinkMirror(now=0.0)
    for t in range(10):
        mirror.receive_datagram(TORN, ("10.0.0.66", 5000), float(t))
        mirror.receive_datagram(HEARTBEAT, GCS, t + 0.5)
    assert list(mirror.clients) == [GCS]
    assert mirror.counters["client_heartbeats"] == 10


def test_newcomers_do_not_push_out_a_client_that_still_sends() -> None:
    mirror = MavlinkMirror(now=0.0, max_clients=8)
    for second in range(5):
        mirror.receive_datagram(HEARTBEAT, GCS, float(second))
        for i in range(8):  # eight new addresses a second
            mirror.receive_datagram(HEARTBEAT, (f"10.9.{second}.{i}", 14550), second + 0.1)
        assert GCS in mirror.live_clients(second + 0.2)
    assert len(mirror.live_clients(5.0)) == 8
    assert mirror.counters["clients_refused"] == 5 * 8 - 7


def test_a_silent_client_stops_being_a_destination_and_frees_its_place() -> None:
    mirror = MavlinkMirror(now=0.0, max_clients=1)
    mirror.receive_datagram(HEARTBEAT, GCS, 0.0)
    assert mirror.live_clients(CLIENT_TIMEOUT_S) == [GCS]
    assert mirror.live_clients(CLIENT_TIMEOUT_S + 0.1) == []
    other = ("10.0.0.7", 14550)
    mirror.receive_datagram(HEARTBEAT, other, CLIENT_TIMEOUT_S + 0.2)
    assert mirror.live_clients(CLIENT_TIMEOUT_S + 0.3) == [other]


def test_fuzzed_datagrams_keep_the_counters_bounded() -> None:
    rng = random.Random(5)
    mirror = MavlinkMirror(now=0.0)
    for i in range(20_000):
        frame = bytearray(HEARTBEAT)
        for _ in range(rng.randint(1, 4)):
            frame[rng.randrange(len(frame))] = rng.randrange(256)
        mirror.receive_datagram(bytes(frame), ("10.0.0.1", 1), i * 0.001)
    assert mirror.counters["ignored_unknown"] > 100
    assert len(mirror.counters) < 20, sorted(mirror.counters)


class _Transport:
    def __init__(self) -> None:
        self.sent: list[tuple[bytes, Any]] = []

    def sendto(self, data: bytes, addr: Any) -> None:
        self.sent.append((data, addr))


def test_the_udp_shell_sends_only_to_live_clients() -> None:
    now = [0.0]
    out = MavlinkOut(clock=lambda: now[0], out=None, listen=("127.0.0.1", 0))
    transport = _Transport()
    out.transport = transport  # type: ignore[assignment]
    out._arm = lambda: None  # type: ignore[method-assign]  # no event loop here
    out._on_datagram(HEARTBEAT, GCS)
    out.on_data("drone1", {"lat_deg": 47.0, "lon_deg": 8.0})
    assert {addr for _, addr in transport.sent} == {GCS}
    transport.sent.clear()
    now[0] = CLIENT_TIMEOUT_S + 1.0  # the GCS went away
    out.on_data("drone1", {"lat_deg": 47.1, "lon_deg": 8.0})
    assert transport.sent == []
