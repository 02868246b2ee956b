"""Who may speak for the autopilot (docs/security.md, 2026-11-24).

MAVLink on the companion's ``udpin`` port is unsigned, and pymavlink's ``udpin`` sends to
whoever sent last. The default URL and the shipped example listened on ``0.0.0.0``: a host on
any of the drone's networks (the radio link among them) that sent a HEARTBEAT was taken for
the autopilot, and got the companion's stream requests, commands and ADSB reports. Now both
listen on loopback; a wildcard URL is still possible, with a warning at start.

The process test runs the shipped ``uav-companion check`` on ``examples/companion.toml`` with
only the port changed; 127.0.0.3 stands for the drone's radio address (every 127/8 address
reaches a socket bound to 0.0.0.0, only 127.0.0.1 one bound to 127.0.0.1).
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from companion.config import parse_config
from companion.mavlink_commands import DEFAULT_MAVLINK_URL, wildcard_mavlink_warning
from tests.integration.test_peers_e2e import free_port
from tests.keys import write_test_keys

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mav

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "companion.toml"
COMPANION = Path(sys.executable).parent / "uav-companion"


def _example_url() -> str:
    import tomllib

    return str(tomllib.loads(EXAMPLE.read_text())["mavlink"]["url"])


def test_the_default_and_the_example_listen_on_loopback() -> None:
    config = parse_config({"drone": {"id": "d1"}})
    assert config.mavlink.url == DEFAULT_MAVLINK_URL == "udpin:127.0.0.1:14550"
    assert _example_url() == DEFAULT_MAVLINK_URL


@pytest.mark.parametrize("url", ["udpin:0.0.0.0:14550", "udp:0.0.0.0:14550", "udpin::14550",
                                 "udpin:[::]:14550"])
def test_a_wildcard_url_is_warned_about(url: str) -> None:
    warning = wildcard_mavlink_warning(url)
    assert warning is not None and "every network interface" in warning


@pytest.mark.parametrize("url", ["udpin:127.0.0.1:14550", "udpin:192.168.144.10:14550",
                                 "udpout:0.0.0.0:14550", "tcp:127.0.0.1:5760", "/dev/serial0"])
def test_an_address_is_not_warned_about(url: str) -> None:
    assert wildcard_mavlink_warning(url) is None


TORN = bytes([0xFD, 255, 0, 0, 0, 1, 1, 0, 0, 0])  # a MAVLink 2 header promising 255 bytes


def _check(tmp_path: Path, send_to: str, *, torn_first: bool = False) -> str:
    """``uav-companion check`` on the example (port changed) while HEARTBEATs of an ArduPilot
    arrive at ``send_to`` (each after a torn frame from another socket: ``torn_first``); its
    stdout."""
    if not COMPANION.exists():
        pytest.skip(f"{COMPANION} missing: install the project in this venv")
    port = free_port()
    keys = write_test_keys(tmp_path / "keys")
    text = EXAMPLE.read_text()
    url = _example_url()
    for old, new in {f'url = "{url}"': f'url = "{url.rpartition(":")[0]}:{port}"',
                     '# fleet_key_file = "/etc/uav-companion/fleet.key"':
                         f'fleet_key_file = "{keys / "fleet.key"}"',
                     '# command_public_key_file = "/etc/uav-companion/command.pub"':
                         f'command_public_key_file = "{keys / "command.pub"}"'}.items():
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    config = tmp_path / "companion.toml"
    config.write_text(text)
    stop = threading.Event()
    link = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    beat = link.heartbeat_encode(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                 mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4,
                                 mav.MAV_STATE_STANDBY).pack(link)

    def speak() -> None:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s, \
                socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as stranger:
            while not stop.wait(0.1):
                if torn_first:
                    stranger.sendto(TORN, (send_to, port))
                s.sendto(beat, (send_to, port))

    talker = threading.Thread(target=speak, daemon=True)
    talker.start()
    try:
        result = subprocess.run([str(COMPANION), "check", "--config", str(config), "--timeout",
                                 "2", "--skip-camera"], capture_output=True, text=True,
                                timeout=60, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    finally:
        stop.set()
        talker.join()
    assert "Traceback" not in result.stderr, result.stderr
    return result.stdout


def test_a_host_on_another_interface_is_not_taken_for_the_autopilot(tmp_path: Path) -> None:
    out = _check(tmp_path, "127.0.0.3")
    assert "ardupilot autopilot" not in out and "no autopilot HEARTBEAT" in out, out


def test_the_autopilot_on_this_computer_still_is(tmp_path: Path) -> None:
    out = _check(tmp_path, "127.0.0.1")
    assert "ardupilot autopilot" in out, out


def test_a_torn_frame_from_another_sender_does_not_hide_the_autopilot(tmp_path: Path) -> None:
    """pymavlink parses one stream for every sender of a ``udpin`` port: before the fix
    "no autopilot HEARTBEAT within 2 s" (each HEARTBEAT was read as the torn frame's
    payload); a local process, or anyone where the port listens wider, could do that."""
    out = _check(tmp_path, "127.0.0.1", torn_first=True)
    assert "ardupilot autopilot" in out, out


def test_frames_sharing_a_datagram_all_arrive() -> None:
    """The torn-frame reset keeps complete frames already in the buffer."""
    from companion.mavlink_commands import MavlinkSettings
    from companion.mavlink_reader import _default_connect

    port = free_port()
    conn = _default_connect(MavlinkSettings(url=f"udpin:127.0.0.1:{port}"))
    link = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    two = (link.heartbeat_encode(2, 3, 1, 4, 3).pack(link)
           + link.attitude_encode(0, 0.1, 0.2, 0.3, 0, 0, 0).pack(link))
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.sendto(two, ("127.0.0.1", port))
            s.sendto(TORN, ("127.0.0.1", port))
            s.sendto(two, ("127.0.0.1", port))
        kinds = []
        for _ in range(10):
            msg = conn.recv_match(blocking=True, timeout=0.5)
            if msg is None:
                break
            kinds.append(msg.get_type())
    finally:
        conn.close()
    assert [k for k in kinds if k != "BAD_DATA"] == ["HEARTBEAT", "ATTITUDE"] * 2, kinds
