"""The built-in vehicle passes the client checks a real ArduCopter and a real PX4 SIH pass
(``autopilot_checks``): heartbeat, streams, first fix and home, parameters, mission up/down,
mode confirmed by HEARTBEAT, arm, takeoff, climb, mission progress, landing.

Run against a real SITL too: ``UAV_TEST_MAVLINK_URL=udpin:0.0.0.0:14550 pytest
tests/sitl/test_sitl_vehicle_conformance.py``, with ``UAV_TEST_AUTOPILOT_CMD`` to have the
test start (and kill) it (docs/companion.md, "Testing against a real autopilot")."""

from __future__ import annotations

import os
import shlex
import socket
import sys
import threading
from pathlib import Path

import pytest

from tests.autopilot_checks import Autopilot, run_all_checks
from tests.autopilot_process import from_environment


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
    assert ap.conn.port.fileno() == -1  # closed: the next client of a one-client port waits
    assert ap.ardupilot == (flavour == "ardupilot")
    assert ap.home is not None
    assert ap.home[:2] == pytest.approx((vehicle.records[0]["home"][0],
                                         vehicle.records[0]["home"][1]), abs=1e-6)


@pytest.mark.timeout(600)
@pytest.mark.skipif(not os.environ.get("UAV_TEST_MAVLINK_URL"),
                    reason="set UAV_TEST_MAVLINK_URL (e.g. udpin:0.0.0.0:14550) to run the same "
                           "checks against a real ArduPilot/PX4 SITL; see docs/companion.md")
def test_real_autopilot_passes_the_checks(tmp_path: Path) -> None:
    # With UAV_TEST_AUTOPILOT_CMD the checks start their own, fresh, autopilot and kill it
    # after, as test_real_autopilot.py does (they ran against nothing: the real-autopilot
    # test had killed its SITL, and the first read raised ConnectionRefusedError).
    process = from_environment(tmp_path / "autopilot.log")
    if process is not None:
        process.start()
    try:
        # The checks are a GCS: they fly on the GCS link when one is named. ArduPilot SITL
        # opens its second serial port (the companion's) only once a client is on the first.
        run_all_checks(os.environ.get("UAV_TEST_MAVLINK_GCS_URL")
                       or os.environ["UAV_TEST_MAVLINK_URL"])
    finally:
        if process is not None:
            process.stop()


@pytest.mark.timeout(120)
def test_the_checks_start_the_autopilot_command_they_are_given(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # UAV_TEST_AUTOPILOT_CMD set to the built-in vehicle, so it runs in the default suite
    port = _free_udp_port()
    monkeypatch.setenv("UAV_TEST_AUTOPILOT_CMD", shlex.join([
        sys.executable, "-m", "sitl.cli", "vehicle", "--port", str(port), "--flavour",
        "ardupilot", "--speedup", "10", "--first-fix", "20"]))
    monkeypatch.setenv("UAV_TEST_MAVLINK_URL", f"udpout:127.0.0.1:{port}")
    monkeypatch.delenv("UAV_TEST_MAVLINK_GCS_URL", raising=False)
    test_real_autopilot_passes_the_checks(tmp_path)
    assert "READY" in (tmp_path / "autopilot.log").read_text()


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def test_a_checks_link_is_closed_when_done() -> None:
    """ArduPilot SITL's TCP port 5760 takes one client at a time. Run after
    test_real_autopilot.py in one pytest, the conformance checks' connection waited
    unaccepted behind that test's link (left to the garbage collector) and failed with "no
    autopilot HEARTBEAT on tcp:127.0.0.1:5760 within 30 s" (ArduCopter 4.5.5 SITL)."""
    from pymavlink.dialects.v20 import ardupilotmega as m

    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    server.settimeout(5)
    port = server.getsockname()[1]
    eof = threading.Event()

    def serve() -> None:  # one client, HEARTBEATs at 10 Hz, until it closes
        client, _ = server.accept()
        client.settimeout(0.1)
        encoder = m.MAVLink(None, srcSystem=1, srcComponent=1)
        hb = m.MAVLink_heartbeat_message(m.MAV_TYPE_QUADROTOR, m.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                         81, 0, 3, 3)
        with client:
            while True:
                try:
                    client.sendall(hb.pack(encoder))
                    if client.recv(4096) == b"":
                        eof.set()
                        return
                except TimeoutError:
                    continue
                except OSError:
                    eof.set()
                    return

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        with Autopilot.connect(f"tcp:127.0.0.1:{port}", timeout_s=5.0) as ap:
            assert ap.ardupilot
        assert eof.wait(5.0), "the link stayed open after the checks"
    finally:
        server.close()
        thread.join(5)
