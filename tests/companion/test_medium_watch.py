"""A shared medium that does not work is told at WARNING (companion/medium_watch.py).

Seen on a netns fleet by hand: ``peers.medium`` on a broadcast address not of the drone's
network (every send: ENETUNREACH, counted at DEBUG), or on another port than the fleet's,
ran with nothing above INFO in the drone's log while every position and status it shared
was lost (the station showed it without a position or a mode, no peer knew it).
"""

from __future__ import annotations

import errno
import logging
import time
from typing import Any

import pytest

from companion.medium import parse_medium
from companion.medium_watch import MediumWatch
from companion.protocol import Decoder, Encoder
from companion.transport import UdpTransport
from tests.keys import TEST_FLEET_KEY
from utility_specs.message import Message

MEDIUM = parse_medium("broadcast:10.99.0.255:14700")
LOG = logging.getLogger("tests.medium_watch")


def warnings(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]


def test_deaf_alone_and_back(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, logger=LOG.name)
    watch = MediumWatch(MEDIUM, LOG, period_s=30.0)
    counters = {"medium_sent": 0, "medium_reports_sent": 0, "medium_own_echo": 0,
                "medium_received": 0}
    assert watch.check(counters) == "ok" and not caplog.records  # nothing sent yet
    counters["medium_sent"] = 40
    assert watch.check(counters) == "deaf"
    assert len(warnings(caplog)) == 1
    assert "peers.medium broadcast:10.99.0.255:14700: nothing heard on the shared medium " \
           "for 30 s, not even this drone's own 40 messages" in warnings(caplog)[0]
    counters["medium_sent"] = 80
    assert watch.check(counters) == "deaf" and len(warnings(caplog)) == 1  # told once
    counters.update(medium_sent=120, medium_own_echo=40)
    assert watch.check(counters) == "alone"
    assert "only this drone's own messages were heard" in warnings(caplog)[1]
    counters.update(medium_sent=160, medium_received=3)
    assert watch.check(counters) == "ok"
    assert caplog.records[-1].levelno == logging.INFO
    assert "other fleet members heard again" in caplog.records[-1].getMessage()


def test_failed_sends_are_told_at_once_then_once_a_minute(caplog: pytest.LogCaptureFixture
                                                          ) -> None:
    watch = MediumWatch(MEDIUM, LOG, repeat_s=60.0)
    exc = OSError(errno.ENETUNREACH, "Network is unreachable")
    for t in range(0, 61, 2):
        watch.send_failed(exc, 100.0 + t)
    told = warnings(caplog)
    assert len(told) == 2, told
    assert "sending on the shared medium failed (Network is unreachable): " in told[0]
    assert "(30 times since)" in told[1]


class _Unreachable:
    """A datagram transport whose every send fails as on a host with no route for it."""

    def __init__(self, owner: UdpTransport, real: Any) -> None:
        self.owner, self.real = owner, real

    def sendto(self, data: bytes, addr: Any) -> None:
        self.owner._on_send_error(OSError(errno.ENETUNREACH, "Network is unreachable"))

    def get_write_buffer_size(self) -> int:
        return 0

    def __getattr__(self, name: str) -> Any:
        return getattr(self.real, name)


async def test_the_transport_tells_a_medium_send_that_failed(caplog: pytest.LogCaptureFixture
                                                             ) -> None:
    t = UdpTransport(encoder=Encoder(1, "d1", TEST_FLEET_KEY),
                     decoder=Decoder(1, TEST_FLEET_KEY, local_id="d1"),
                     remote_addr=("127.0.0.1", 9), local_addr=("127.0.0.1", 0),
                     medium=parse_medium("broadcast:127.255.255.255:14799"))
    await t.start()
    try:
        real = t._transport
        t._transport = _Unreachable(t, real)  # type: ignore[assignment]
        position = Message(sender="d1", seq=1, type="position", t_gen=time.time(), size=20,
                           data={"lat_deg": 47.0, "lon_deg": 8.0})
        t.send_message(position, b"")  # to the ground: not the medium's problem
        assert not warnings(caplog)
        t.send_message(position, b"", shared=True)
        assert len(warnings(caplog)) == 1
        assert warnings(caplog)[0].startswith("peers.medium broadcast:127.255.255.255:14799: "
                                              "sending on the shared medium failed")
        t._transport = real
    finally:
        t._close()


async def test_another_member_with_our_id_is_told(caplog: pytest.LogCaptureFixture) -> None:
    """Seen on a netns fleet: a second drone with a copied config (drone.id = "drone1") made
    the real drone1's position age 19 s at its peers, flipped its status there, and the
    station dropped 246 datagrams as replayed; no log said why."""
    import asyncio
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    medium = parse_medium(f"broadcast:127.255.255.255:{port}")

    def drone() -> UdpTransport:
        return UdpTransport(encoder=Encoder(1, "drone1", TEST_FLEET_KEY),
                            decoder=Decoder(1, TEST_FLEET_KEY, local_id="drone1"),
                            remote_addr=("127.0.0.1", 9), local_addr=("127.0.0.1", 0),
                            medium=medium)

    real, twin = drone(), drone()
    await real.start()
    try:
        position = Message(sender="drone1", seq=1, type="position", t_gen=time.time(),
                           size=20, data={"lat_deg": 47.0, "lon_deg": 8.0})
        real.send_message(position, b"", shared=True)  # its own echo: not a twin
        async with asyncio.timeout(5):
            while real.counters["medium_own_echo"] < 1:
                await asyncio.sleep(0.01)
        assert not warnings(caplog)
        await twin.start()
        for _ in range(3):
            twin.send_message(position, b"", shared=True)
        async with asyncio.timeout(5):
            while real.counters["medium_own_echo"] < 4:
                await asyncio.sleep(0.01)
        told = [w for w in warnings(caplog) if w.startswith("drone.id: another fleet member")]
        twin_port = twin.local_address[1]
        assert len(told) == 1  # three datagrams from the twin, told once
        assert any(f"127.0.0.1:{twin_port} sends with this drone's id" in w for w in told)
    finally:
        real._close()
        twin._close()
