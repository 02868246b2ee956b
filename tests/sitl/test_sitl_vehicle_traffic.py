"""The built-in vehicle's traffic list: ADSB_VEHICLE in, as ArduPilot's AP_ADSB and PX4 keep it
(sitl/vehicle/traffic.py), the list streamed back, and the optional avoidance reaction."""

from __future__ import annotations

import socket
import time
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sitl.vehicle.core import DEFAULT_HOME
from sitl.vehicle.flavour import ARDUPILOT, PX4, Mode

HOME_LAT, HOME_LON, HOME_ALT = DEFAULT_HOME.lat_deg, DEFAULT_HOME.lon_deg, DEFAULT_HOME.alt_m
COORDS_ALT_HDG_VEL_CALL = 1 | 2 | 4 | 8 | 16


def adsb(icao: int = 0x123456, *, north_m: float = 50.0, up_m: float = 0.0, tslc: int = 0,
         flags: int = COORDS_ALT_HDG_VEL_CALL, callsign: bytes = b"DRONE2",
         lat: float | None = None) -> Any:
    lat_deg = HOME_LAT + north_m / 111_195.0 if lat is None else lat
    return mavlink.MAVLink_adsb_vehicle_message(
        icao, round(lat_deg * 1e7), round(HOME_LON * 1e7), 1, round((HOME_ALT + up_m) * 1000),
        9000, 500, 0, callsign, 14, tslc, flags, 0)


def set_param(gcs: Any, name: str, value: float) -> None:
    gcs.send(mavlink.MAVLink_param_set_message(1, 1, name.encode(), value, 9))


def test_ardupilot_ignores_traffic_until_adsb_type_is_set(make_gcs):
    gcs = make_gcs(flavour=ARDUPILOT)
    gcs.send(adsb())
    assert gcs.core.traffic.vehicles == {}
    assert gcs.core.traffic.counters["adsb_disabled"] == 1
    set_param(gcs, "ADSB_TYPE", 1)
    gcs.send(adsb(tslc=2))
    [entry] = gcs.core.traffic.snapshot(gcs.now)
    assert entry["icao_address"] == 0x123456 and entry["callsign"] == "DRONE2"
    assert entry["age_s"] == 2.0  # last update = now - tslc
    assert entry["alt_amsl_m"] == pytest.approx(HOME_ALT)
    gcs.run_until(3.5)
    assert gcs.core.traffic.vehicles  # 5.5 s old: still there at the 1 s tick...
    gcs.run_until(4.5)  # ...dropped past 5 s without an update (VEHICLE_TIMEOUT_MS)
    assert gcs.core.traffic.vehicles == {}
    assert gcs.core.traffic.counters["timed_out"] == 1


def test_ardupilot_filters_like_ap_adsb(make_gcs):
    gcs = make_gcs(flavour=ARDUPILOT, params={"ADSB_TYPE": 1, "ADSB_ICAO_ID": 0xABCDEF})
    gcs.run_until(0.5)  # a fix and a position: the radius filter applies
    gcs.send(adsb(icao=0x1000000))  # 25 bits
    gcs.send(adsb(icao=2, flags=4 | 8))  # neither coords nor altitude valid
    gcs.send(adsb(icao=3, tslc=6))  # older than 5 s already
    gcs.send(adsb(icao=4, north_m=2500.0))  # beyond ADSB_LIST_RADIUS 2000 m
    gcs.send(adsb(icao=0xABCDEF))  # ourself
    gcs.send(mavlink.MAVLink_adsb_vehicle_message(6, 0, 0, 1, 0, 0, 0, 0, b"ZERO", 14, 0, 3,
                                                  0))  # 0/0
    assert gcs.core.traffic.vehicles == {}
    c = gcs.core.traffic.counters
    assert (c["ignored_icao_over_24_bits"], c["ignored_no_valid_position_flags"],
            c["ignored_too_old"], c["ignored_out_of_radius"], c["ignored_ourself"],
            c["ignored_zero_position"]) == (1, 1, 1, 1, 1, 1)
    gcs.send(adsb(icao=7, flags=2))  # altitude alone passes AP_ADSB's any-of flag test
    assert set(gcs.core.traffic.vehicles) == {7}
    gcs.send(adsb(icao=7, north_m=2500.0))  # a tracked vehicle that leaves the radius
    assert gcs.core.traffic.vehicles == {}


def test_full_list_keeps_the_nearest(make_gcs):
    gcs = make_gcs(flavour=ARDUPILOT, params={"ADSB_TYPE": 1, "ADSB_LIST_MAX": 2})
    gcs.run_until(0.5)
    gcs.send(adsb(icao=1, north_m=100.0))
    gcs.send(adsb(icao=2, north_m=300.0))
    gcs.send(adsb(icao=3, north_m=500.0))  # farther than both: not taken
    assert set(gcs.core.traffic.vehicles) == {1, 2}
    gcs.send(adsb(icao=4, north_m=200.0))  # nearer than the farthest (2): replaces it
    assert set(gcs.core.traffic.vehicles) == {1, 4}


def test_px4_takes_traffic_without_setup_and_streams_it_back(make_gcs):
    gcs = make_gcs(flavour=PX4)
    gcs.send(adsb(north_m=5000.0))  # PX4 has no list radius
    gcs.clear()
    gcs.run_until(2.0)
    echoed = gcs.of_type("ADSB_VEHICLE")
    assert echoed, "the traffic list is streamed to the clients"
    last = echoed[-1]
    assert (last.ICAO_address, last.callsign, last.emitter_type) == (0x123456, "DRONE2", 14)
    assert last.tslc == 2  # its age, not the tslc it came with


def test_ardupilot_avoidance_climbs_away_when_enabled(make_gcs):
    gcs = make_gcs(flavour=ARDUPILOT, params={"ADSB_TYPE": 1, "AVD_ENABLE": 1,
                                             "AVD_F_ACTION": 2, "AVD_F_DIST_XY": 100,
                                             "AVD_F_DIST_Z": 30})
    fc = gcs.core.fc
    assert fc.set_mode(Mode.GUIDED).ok and fc.arm().ok
    assert fc.takeoff(10.0).ok
    gcs.run_until(20.0)
    assert -fc.state.position_ned_m[2] == pytest.approx(10.0, abs=1.0)
    gcs.send(adsb(north_m=300.0, up_m=10.0))  # beyond AVD_F_DIST_XY: no threat
    gcs.run_until(21.0)
    assert not any("Avoid" in m.text for m in gcs.of_type("STATUSTEXT"))
    gcs.send(adsb(north_m=40.0, up_m=10.0))  # 40 m away at our height
    texts = [m.text for m in gcs.of_type("STATUSTEXT")]
    assert any(t.startswith("Avoid: traffic DRONE2 40m") for t in texts), texts
    gcs.run_until(40.0, stop=lambda: -fc.state.position_ned_m[2] > 38.0)
    assert -fc.state.position_ned_m[2] > 38.0  # climbed AVD_F_DIST_Z above it


def test_avoidance_is_off_by_default(make_gcs):
    gcs = make_gcs(flavour=ARDUPILOT, params={"ADSB_TYPE": 1})
    fc = gcs.core.fc
    assert fc.set_mode(Mode.GUIDED).ok and fc.arm().ok and fc.takeoff(10.0).ok
    gcs.run_until(15.0)
    gcs.send(adsb(north_m=5.0, up_m=10.0))
    gcs.run_until(20.0)
    assert not any("Avoid" in m.text for m in gcs.of_type("STATUSTEXT"))
    assert fc.mode is Mode.GUIDED and -fc.state.position_ned_m[2] == pytest.approx(10.0,
                                                                                     abs=1.0)


def test_vehicle_process_lists_traffic_it_was_sent(vehicle_process):
    """`uav-sitl vehicle` over real UDP: ADSB_VEHICLE in, the list streamed back."""
    vehicle = vehicle_process("--flavour", "ardupilot", "--param", "ADSB_TYPE=1")
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.settimeout(0.2)
    tx = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    rx = mavlink.MAVLink(None)
    seen: dict[int, Any] = {}
    try:
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and not {0x00AA01, 0x00AA02} <= set(seen):
            for icao, name in ((0x00AA01, b"DRONE2"), (0x00AA02, b"DRONE3")):
                sock.sendto(adsb(icao=icao, callsign=name).pack(tx),
                            ("127.0.0.1", vehicle.port))
            try:
                data, _ = sock.recvfrom(2048)
            except TimeoutError:
                continue
            for msg in rx.parse_buffer(data) or []:
                if msg.get_type() == "ADSB_VEHICLE":
                    seen[msg.ICAO_address] = msg
    finally:
        sock.close()
    assert {seen[0x00AA01].callsign, seen[0x00AA02].callsign} == {"DRONE2", "DRONE3"}
