"""A drone whose clock is off is named, with how far off, on both ends.

The station refuses every datagram more than ``clock_tolerance_s`` (30 s) off its clock. A
Raspberry Pi has no real-time clock: without NTP in the field it boots at the time it last
saved. Before, such a drone never got a tile, the dashboard's alert "datagrams dropped
(stale): N" named nobody, and neither log said a word. (Seen by running a companion under
``faketime -f -120s``: 941 datagrams refused in 25 s, nothing else.)
"""

from __future__ import annotations

import json
import logging
import re
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

from companion.clock_check import ClockCheck, clock_problem
from companion.protocol import Decoder, Encoder, PacketDropped
from companion.telemetry import SystemTimeSample
from ground_station.clock_watch import TELL_EVERY_S
from ground_station.fleet import FleetView
from tests.keys import TEST_FLEET_KEY
from tests.station_process import running_station
from utility_specs.message import Message

KEY = b"fleet-clock-test-key-0123456789ab"
NOW = 1_796_000_000.0


def position(sender: str, t: float) -> Message:
    return Message(sender=sender, seq=1, type="position", t_gen=t, t_sent=t, t_rcv=None,
                   size=40, data={"lat": 47.0, "lon": 8.0})


def test_a_stale_refusal_names_the_authenticated_sender_and_its_skew() -> None:
    encoder = Encoder(1, "drone7", KEY)
    decoder = Decoder(1, KEY, local_id="gs")
    for datagram in encoder.fragment(position("drone7", NOW - 120.0), b"", NOW - 120.0):
        decoder.receive_datagram(datagram, ("10.0.0.7", 14600), NOW)
    event = decoder.next_event()
    assert isinstance(event, PacketDropped) and event.reason == "stale"
    assert event.sender == "drone7" and event.skew_s == pytest.approx(-120.0)
    forged = Encoder(1, "drone7", b"another-fleet-key-0123456789abcd")
    for datagram in forged.fragment(position("drone7", NOW - 120.0), b"", NOW - 120.0):
        decoder.receive_datagram(datagram, ("10.0.0.9", 14600), NOW)
    event = decoder.next_event()  # refused for its tag first: no sender to name
    assert isinstance(event, PacketDropped) and event.reason == "bad_tag"
    assert event.sender is None and event.skew_s is None


def test_the_dashboard_names_the_drone_once_a_minute(caplog: pytest.LogCaptureFixture) -> None:
    fleet = FleetView(high_utility=None, link_lost_s=3.0, clock_tolerance_s=30.0)
    caplog.set_level(logging.WARNING, logger="ground_station.clock")
    for k in range(200):  # 20 s of refusals, then a minute later
        fleet.on_drop("stale", now=NOW + 0.1 * k, drone="drone7", skew_s=-120.2)
    fleet.on_drop("stale", now=NOW + TELL_EVERY_S + 1.0, drone="drone7", skew_s=-120.2)
    fleet.on_drop("stale", now=NOW, drone="drone8", skew_s=3600.0)
    alerts = fleet.take_new_alerts()
    assert [(a.drone, a.kind, a.level) for a in alerts] == [
        ("drone7", "clock", "error"), ("drone7", "clock", "error"), ("drone8", "clock", "error")]
    assert alerts[0].text == (
        "datagrams refused: its clock is 120 s behind this station's (clock_tolerance_s = 30): "
        "set the drone's clock (NTP, or chrony with the autopilot's GPS time), or this "
        "computer's")
    assert "3600 s ahead of this station's" in alerts[2].text
    assert fleet.drops["stale"] == 202
    assert [r.getMessage()[:7] for r in caplog.records] == ["drone7:", "drone7:", "drone8:"]


def test_the_companion_checks_its_clock_against_the_autopilots_gps_time(
        caplog: pytest.LogCaptureFixture) -> None:
    assert clock_problem(NOW, NOW + 3.0) is None
    assert clock_problem(NOW, None) is None
    assert clock_problem(NOW, 12.5) is None  # an autopilot's own counter, not GPS time
    problem = clock_problem(NOW - 120.0, NOW)
    assert problem is not None and problem.startswith(
        "this computer's clock is 120 s behind the autopilot's GPS time")
    monotonic = [0.0]
    check = ClockCheck(lambda: monotonic[0])
    caplog.set_level(logging.INFO, logger="companion.clock")
    for k in range(700):  # 700 s of SYSTEM_TIME at 1 Hz, 120 s off
        monotonic[0] = float(k)
        check.on_sample(SystemTimeSample(t=NOW + k - 120.0, unix_time_s=NOW + k,
                                         time_boot_s=float(k)))
    check.on_sample(SystemTimeSample(t=NOW + 701, unix_time_s=NOW + 701, time_boot_s=701.0))
    assert [r.levelname for r in caplog.records] == ["WARNING", "WARNING", "INFO"]
    assert not check.off


@pytest.mark.timeout(60)
def test_the_built_in_vehicle_tells_utc_as_a_real_gps(tmp_path: Path) -> None:
    """Its SYSTEM_TIME was a fixed 2023 epoch: every companion's clock looked years off."""
    from pymavlink import mavutil

    proc = subprocess.Popen([sys.executable, "-m", "sitl.cli", "vehicle", "--port", "0",
                             "--first-fix", "0", "--flavour", "px4"],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        port = json.loads(line.split(" ", 1)[1])["port"]
        conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255)
        conn.mav.heartbeat_send(6, 8, 0, 0, 0)
        msg = conn.recv_match(type="SYSTEM_TIME", blocking=True, timeout=20)
        assert msg is not None
        assert abs(msg.time_unix_usec / 1e6 - time.time()) < 2.0
    finally:
        proc.terminate()
        proc.wait(10)


def test_a_station_names_a_drone_whose_clock_is_behind(tmp_path: Path) -> None:
    """The shipped ``uav-ground-station run``: its fleet API and its log name the drone."""
    with running_station(tmp_path) as station:
        udp_port = 0
        deadline = time.monotonic() + 10
        while not udp_port and time.monotonic() < deadline:
            found = re.search(r"udp://127\.0\.0\.1:(\d+)", station.log_text())
            udp_port = int(found.group(1)) if found else 0
        encoder = Encoder(1, "drone7", TEST_FLEET_KEY)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            for _ in range(5):
                t = time.time() - 120.0
                for d in encoder.fragment(position("drone7", t), b"", t):
                    s.sendto(d, ("127.0.0.1", udp_port))
                time.sleep(0.1)
        alerts: list[dict[str, object]] = []
        deadline = time.monotonic() + 10
        while not alerts and time.monotonic() < deadline:
            request = urllib.request.Request(
                f"http://127.0.0.1:{station.port}/api/fleet",
                headers={"Authorization": f"Bearer {station.token}"})
            with urllib.request.urlopen(request, timeout=5) as reply:
                alerts = [a for a in json.loads(reply.read())["alerts"] if a["kind"] == "clock"]
            time.sleep(0.2)
        assert [(a["drone"], str(a["text"])[:44]) for a in alerts] == [
            ("drone7", "datagrams refused: its clock is 120 s behind")]
        assert "WARNING ground_station.clock: drone7: datagrams refused" in station.log_text()
