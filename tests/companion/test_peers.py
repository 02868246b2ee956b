"""Peer state on each drone (companion/peers.py): sans-I/O with explicit time, the ADSB_VEHICLE
it injects (decoded by pymavlink and by the built-in vehicle), and the /peers endpoint."""

from __future__ import annotations

import asyncio
import json
import zlib
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.config import ConfigError, parse_config
from companion.peers import (
    AdsbInjector,
    PeerHttp,
    PeerServices,
    PeersSettings,
    PeerTable,
    callsign_for,
    icao_for,
    parse_peers_settings,
)
from companion.protocol import MessageReassembled
from sitl.vehicle.core import DEFAULT_HOME, VehicleConfig, VehicleCore
from sitl.vehicle.flavour import ARDUPILOT
from utility_specs.message import Message

LAT, LON = DEFAULT_HOME.lat_deg, DEFAULT_HOME.lon_deg


def msg(sender: str, type_: str, t_gen: float, **data: object) -> Message:
    return Message(sender=sender, seq=0, type=type_, t_gen=t_gen, size=40, data=dict(data))


def test_identities() -> None:
    assert icao_for("drone2") == zlib.crc32(b"drone2") & 0xFFFFFF
    assert callsign_for("drone-2.a") == "DRONE2A"
    assert callsign_for("a-very-long-drone-id") == "AVERYLON"
    assert callsign_for("--") == "UAV"


@settings(max_examples=60)
@given(st.text(min_size=1, max_size=32))
def test_identities_fit_ads_b(drone: str) -> None:
    assert 1 <= icao_for(drone) <= 0xFFFFFF
    call = callsign_for(drone)
    assert 1 <= len(call) <= 8 and call.isascii() and call.isalnum() and call.upper() == call


def test_table_keeps_latest_state_with_ages() -> None:
    t = PeerTable("drone1")
    t.on_message(msg("drone1", "position", 99.0, lat_deg=LAT, lon_deg=LON), now=100.0)
    assert t.peers == {}  # our own echo
    t.on_message(msg("drone2", "position", 100.0, lat_deg=LAT, lon_deg=LON, alt_rel_m=20.0,
                     alt_amsl_m=508.0, heading_deg=90.0, pose_age_s=0.5), now=100.2)
    t.on_message(msg("drone2", "battery", 100.5, level=0.8), now=100.6)
    t.on_message(msg("drone2", "status", 100.7, mode="GUIDED", armed=True, secret="x"),
                 now=100.8)
    t.on_message(msg("drone2", "position", 101.5, lat_deg=LAT + 1e-4, lon_deg=LON,
                     alt_rel_m=21.0, alt_amsl_m=509.0), now=101.6)
    t.on_message(msg("drone2", "position", 100.9, lat_deg=0.5, lon_deg=0.5), now=101.7)  # late
    snap = t.snapshot(102.0)
    [p] = snap["peers"]
    assert p["drone"] == "drone2"
    assert p["position"]["lat_deg"] == LAT + 1e-4 and p["position"]["age_s"] == 0.5
    vn, ve, vd = p["position"]["velocity_ned_m_s"]
    assert vn == pytest.approx(11.12 / 2.0, rel=1e-2)  # 11.1 m north in 2 s (99.5 -> 101.5)
    assert ve == pytest.approx(0.0, abs=1e-6) and vd == pytest.approx(-0.5)
    assert p["battery"] == {"level": 0.8, "age_s": 1.5}
    assert p["status"] == {"mode": "GUIDED", "armed": True, "age_s": pytest.approx(1.3)}
    assert t.counters["older_position"] == 1 and t.counters["own"] == 1
    assert t.forget_silent(200.0) == ["drone2"] and t.peers == {}


def test_adsb_reports_carry_the_peer() -> None:
    t = PeerTable("drone1")
    t.on_message(msg("drone2", "position", 10.0, lat_deg=LAT, lon_deg=LON, alt_amsl_m=500.0,
                     vn_m_s=0.0, ve_m_s=3.0, vd_m_s=-1.0), now=10.1)
    t.on_message(msg("drone3", "battery", 10.0, level=0.5), now=10.1)  # no position: none
    [r] = t.adsb_reports(now=13.7)
    decoded = mavlink.MAVLink(None).parse_buffer(
        mavlink.MAVLink_adsb_vehicle_message(*r.args()).pack(mavlink.MAVLink(None)))[0]
    assert decoded.ICAO_address == icao_for("drone2") and decoded.callsign == "DRONE2"
    assert (decoded.lat, decoded.lon, decoded.altitude) == (round(LAT * 1e7), round(LON * 1e7),
                                                          500_000)
    assert decoded.tslc == 3  # whole seconds since the position was observed
    assert (decoded.hor_velocity, decoded.ver_velocity, decoded.heading) == (300, 100, 9000)
    assert decoded.flags == 1 | 2 | 4 | 8 | 16 and decoded.emitter_type == 14


def test_injected_peers_land_in_the_vehicles_traffic_list() -> None:
    """What the injector writes, the built-in ArduPilot (ADSB_TYPE=1) tracks."""
    core = VehicleCore(VehicleConfig(flavour=ARDUPILOT, first_fix_s=0.0,
                                     params={"ADSB_TYPE": 1}), now=0.0)
    t = PeerTable("drone1")
    for i, name in enumerate(("drone2", "drone3", "drone4")):
        t.on_message(msg(name, "position", 0.5, lat_deg=LAT + 1e-4 * (i + 1), lon_deg=LON,
                         alt_amsl_m=DEFAULT_HOME.alt_m + 10), now=0.6)
    tx = mavlink.MAVLink(None, srcSystem=1, srcComponent=191)
    injector = AdsbInjector(t, rate_hz=1.0, clock=lambda: 1.0,
                            send=lambda m: core.receive_datagram(m.pack(tx), ("c", 1), 1.0))
    assert injector.inject(1.0) == 3
    listed = {e["callsign"]: e["age_s"] for e in core.traffic.snapshot(1.0)}
    assert listed == {"DRONE2": 0.0, "DRONE3": 0.0, "DRONE4": 0.0}


def test_injector_counts_a_failing_link() -> None:
    t = PeerTable("drone1")
    t.on_message(msg("drone2", "position", 0.0, lat_deg=LAT, lon_deg=LON), now=0.0)

    def down(_: object) -> None:
        raise RuntimeError("MAVLink service not running")

    injector = AdsbInjector(t, rate_hz=2.0, clock=lambda: 0.0, send=down)
    assert injector.inject(0.0) == 0 and injector.counters["send_errors"] == 1


def test_http_is_read_only_json() -> None:
    t = PeerTable("drone1")
    t.on_message(msg("drone2", "battery", 5.0, level=0.4), now=5.0)
    http = PeerHttp(t, clock=lambda: 6.0, host="127.0.0.1", port=0)
    assert http.respond(b"GET /peers HTTP/1.1") == (200, t.snapshot(6.0))
    status, body = http.respond(b"GET /peers/drone2 HTTP/1.0")
    assert status == 200 and body["battery"] == {"level": 0.4, "age_s": 1.0}
    assert http.respond(b"GET /peers/nobody HTTP/1.0")[0] == 404
    assert http.respond(b"POST /peers HTTP/1.0")[0] == 405
    assert http.respond(b"garbage")[0] == 400


async def test_http_serves_over_a_socket() -> None:
    t = PeerTable("drone1")
    t.on_message(msg("drone2", "battery", 5.0, level=0.4), now=5.0)
    http = PeerHttp(t, clock=lambda: 6.0, host="127.0.0.1", port=0)
    host, port = await http.start()
    try:
        reader, writer = await asyncio.open_connection(host, port)
        writer.write(b"GET /peers HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        raw = await reader.read()
        writer.close()
        head, _, body = raw.partition(b"\r\n\r\n")
        assert head.startswith(b"HTTP/1.0 200 OK")
        assert json.loads(body)["peers"][0]["drone"] == "drone2"
        reader, writer = await asyncio.open_connection(host, port)
        writer.write(b"X" * 5000)  # no end of headers within the limit
        raw = await reader.read()
        writer.close()
        assert raw.startswith(b"HTTP/1.0 400")
    finally:
        http.close()


def test_services_share_only_peer_types_and_only_with_a_medium() -> None:
    on = PeerServices(PeersSettings(medium="broadcast:127.255.255.255:14700"), own_id="d1",
                      clock=lambda: 1.0, peer_types=frozenset({"position"}))
    assert on.shared("position") and not on.shared("image")
    off = PeerServices(PeersSettings(), own_id="d1", clock=lambda: 1.0,
                       peer_types=frozenset({"position"}))
    assert not off.shared("position")
    on.on_event(MessageReassembled(message=msg("d2", "battery", 0.5, level=0.3),
                                   payload=b"", addr=("127.0.0.1", 1), t_rcv=1.0,
                                   fragments=1))
    assert on.table.peers["d2"].battery == 0.3


def test_settings_are_validated() -> None:
    assert parse_peers_settings({}) == PeersSettings()
    s = parse_peers_settings({"medium": "multicast:239.255.42.99:14700:127.0.0.1",
                              "adsb_rate_hz": 2, "http": "127.0.0.1:8091"})
    assert s.adsb_rate_hz == 2.0 and s.http == "127.0.0.1:8091"
    for bad in ({"medium": "unicast:1.2.3.4:5"}, {"medium": "multicast:10.0.0.1:14700"},
                {"adsb_rate_hz": -1}, {"adsb_rate_hz": True}, {"http": "8091"},
                {"forget_after_s": 0}, {"colour": "red"}):
        with pytest.raises(ValueError):
            parse_peers_settings(bad)
    with pytest.raises(ConfigError, match=r"peers\.adsb_rate_hz"):
        parse_config({"drone": {"id": "d1"}, "peers": {"adsb_rate_hz": "fast"}})


async def test_a_busy_http_port_is_logged_and_the_rest_runs(caplog: pytest.LogCaptureFixture
                                                            ) -> None:
    import socket

    busy = socket.socket()
    busy.bind(("127.0.0.1", 0))
    busy.listen()
    port = busy.getsockname()[1]
    sent: list[object] = []
    services = PeerServices(PeersSettings(http=f"127.0.0.1:{port}", adsb_rate_hz=20.0),
                            own_id="d1", clock=lambda: 1.0, send_mavlink=sent.append)
    services.table.on_message(msg("d2", "position", 0.9, lat_deg=LAT, lon_deg=LON), now=1.0)
    task = asyncio.create_task(services.run())
    try:
        async with asyncio.timeout(5):
            while not sent:
                await asyncio.sleep(0.01)
    finally:
        services.stop()
        await task
        busy.close()
    assert services.http is None
    assert any("peers.http: cannot serve on" in r.getMessage() for r in caplog.records)


async def test_a_silent_peer_is_forgotten_without_adsb(caplog: pytest.LogCaptureFixture
                                                        ) -> None:
    """forget_after_s held only while ADSB_VEHICLE injection ran: with adsb_rate_hz = 0 (the
    default) a stopped drone stayed in /peers and the dashboard's peers row for ever (seen
    on a 3-drone netns fleet: drone7 stopped, still listed 55 s later and growing)."""
    caplog.set_level("INFO", logger="companion.peers")
    now = [100.0]
    services = PeerServices(PeersSettings(medium="broadcast:127.255.255.255:14700",
                                          forget_after_s=5.0),
                            own_id="d1", clock=lambda: now[0], forget_interval_s=0.01)
    assert services.injector is None
    services.table.on_message(msg("d2", "position", 99.9, lat_deg=LAT, lon_deg=LON), now=100.0)
    task = asyncio.create_task(services.run())
    try:
        await asyncio.sleep(0.05)
        assert services.status_fields()["peers"] == {"d2": 0.1}  # heard 0 s ago: kept
        now[0] = 106.0
        async with asyncio.timeout(5):
            while services.table.peers:
                await asyncio.sleep(0.01)
    finally:
        services.stop()
        await task
    assert services.status_fields()["peers"] == {}
    assert services.table.snapshot(now[0])["peers"] == []
    assert any("peer d2 forgotten" in r.getMessage() and "peers.forget_after_s" in
               r.getMessage() for r in caplog.records)


def test_peer_settings_without_a_medium_are_told(tmp_path: Path) -> None:
    """A spec sharing types with peers (or peers.http, adsb_rate_hz) without peers.medium ran
    without a word: its shared types went to the ground only and /peers stayed empty (seen by
    hand: `uav-companion run` with builtin:peer_sharing and no medium, nothing above INFO)."""
    from companion.app import check_setup
    from companion.peers import peers_setup_problem
    from tests.keys import write_test_keys

    shared = frozenset({"position", "status"})
    assert peers_setup_problem(PeersSettings(), frozenset()) is None
    assert peers_setup_problem(PeersSettings(medium="broadcast:10.0.0.255:14700"),
                               shared) is None
    problem = peers_setup_problem(PeersSettings(http="127.0.0.1:8091", adsb_rate_hz=1.0),
                                  shared)
    assert problem is not None and problem.startswith(
        "peers.medium is not set: the mission spec shares position, status with peers")
    assert "GET /peers on 127.0.0.1:8091 will list no peer" in problem
    assert "ADSB_VEHICLE" in problem
    keys = write_test_keys(tmp_path / "keys")
    config = parse_config({"drone": {"id": "d1"}, "mission": {"spec": "builtin:peer_sharing"},
                           "ground_station": {"fleet_key_file": str(keys / "fleet.key"),
                                              "command_public_key_file":
                                                  str(keys / "command.pub")}})
    assert any(line.startswith("peers: peers.medium is not set")
               for line in check_setup(config))
