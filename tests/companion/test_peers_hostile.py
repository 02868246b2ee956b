"""The peer side against hostile input: a fleet member's position with huge finite numbers,
and a DNS-rebinding page reading ``GET /peers``.

* ``adsb_reports`` rounded ``hypot(1e308, 1e308) * 100`` (inf) and raised OverflowError,
  outside the injector's per-send guard: the ADSB_VEHICLE loop of every peer stopped.
* A position stamped far in the future froze that peer's position: every true one after it
  was ``older_position`` until the peer was forgotten.
* The unauthenticated ``/peers`` answered any ``Host``: a page on ``evil.example`` rebound to
  127.0.0.1 is same-origin with it and could read every peer's position.
"""

from __future__ import annotations

import asyncio

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.peer_table import MAX_FUTURE_S
from companion.peers import AdsbInjector, PeerHttp, PeerTable
from tests.companion.test_peers import LAT, LON, msg

HUGE = [
    {"vn_m_s": 1e308, "ve_m_s": 1e308, "vd_m_s": -1e308, "alt_amsl_m": 1e300},
    {"vn_m_s": -1e308, "ve_m_s": 0.0, "vd_m_s": 1e308, "alt_amsl_m": -1e300,
     "heading_deg": 1e308},
    {"heading_deg": -1e308, "alt_amsl_m": 3e6},
]


@pytest.mark.parametrize("extra", HUGE)
def test_huge_numbers_become_valid_adsb_vehicle_messages(extra: dict[str, float]) -> None:
    table = PeerTable("drone1")
    table.on_message(msg("drone2", "position", 10.0, lat_deg=LAT, lon_deg=LON, **extra),
                     now=10.0)
    [report] = table.adsb_reports(now=11.0)
    packed = mavlink.MAVLink_adsb_vehicle_message(*report.args()).pack(mavlink.MAVLink(None))
    decoded = mavlink.MAVLink(None).parse_buffer(packed)[0]
    assert -2**31 <= decoded.altitude < 2**31 and 0 <= decoded.heading < 36000
    assert 0 <= decoded.hor_velocity <= 65535 and -32768 <= decoded.ver_velocity <= 32767


def test_one_hostile_peer_does_not_stop_the_others() -> None:
    table = PeerTable("drone1")
    table.on_message(msg("drone2", "position", 10.0, lat_deg=LAT, lon_deg=LON, **HUGE[0]),
                     now=10.0)
    table.on_message(msg("drone3", "position", 10.0, lat_deg=LAT, lon_deg=LON), now=10.0)
    sent: list[object] = []
    injector = AdsbInjector(table, rate_hz=1.0, clock=lambda: 11.0, send=sent.append)
    assert injector.inject(11.0) == 2 and injector.counters["send_errors"] == 0


@pytest.mark.parametrize(("host", "status"), [
    (None, 200), ("127.0.0.1", 200), ("127.0.0.1:14710", 200), ("localhost:14710", 200),
    ("LOCALHOST.", 200), ("[::1]:14710", 200), ("10.0.0.5", 200),
    ("evil.example", 421), ("evil.example:14710", 421), ("127.0.0.1.evil.example", 421),
    ("", 421),
])
def test_only_ip_literals_and_localhost_are_served(host: str | None, status: int) -> None:
    http = PeerHttp(PeerTable("drone1"), clock=lambda: 1.0, host="127.0.0.1", port=0)
    assert http.respond(b"GET /peers HTTP/1.1", host=host)[0] == status


async def test_a_rebound_name_gets_421_over_a_socket() -> None:
    table = PeerTable("drone1")
    table.on_message(msg("drone2", "position", 5.0, lat_deg=LAT, lon_deg=LON), now=5.0)
    http = PeerHttp(table, clock=lambda: 6.0, host="127.0.0.1", port=0)
    host, port = await http.start()
    try:
        reader, writer = await asyncio.open_connection(host, port)
        writer.write(f"GET /peers HTTP/1.1\r\nHost: evil.example:{port}\r\n\r\n".encode())
        raw = await reader.read()
        writer.close()
        assert raw.startswith(b"HTTP/1.0 421 Misdirected Request")
        assert str(LAT).encode() not in raw
    finally:
        http.close()


def test_a_far_future_position_does_not_freeze_the_peer() -> None:
    table = PeerTable("drone1")
    table.on_message(msg("drone2", "position", 1e9, lat_deg=LAT, lon_deg=LON), now=10.0)
    assert table.counters["future_t_gen"] == 1
    # the true positions after it count once our clock passes the clamped time
    table.on_message(msg("drone2", "position", 10.0 + MAX_FUTURE_S + 0.5,
                         lat_deg=LAT + 0.001, lon_deg=LON), now=10.0 + MAX_FUTURE_S + 0.5)
    assert table.peers["drone2"].lat_deg == pytest.approx(LAT + 0.001)
    assert "older_position" not in table.counters
