"""A field operator's flight: the companion on a serial line, a GCS on the vehicle at the same
time, the dashboard checked against the autopilot after every step.

Real processes: ``uav-ground-station run``, ``uav-sitl vehicle`` (both flavours),
``uav-companion run`` built from ``examples/companion.toml`` with ``url`` a serial device at
57600 baud. The serial line is a pseudo-terminal made by socat (the "cable": killing socat
pulls it, a new socat on the same path plugs it back), bridged to the vehicle's UDP port,
where a pymavlink GCS (system 255, HEARTBEAT at 1 Hz, as QGroundControl) also talks. The
ground station's ``/api/fleet`` is what the dashboard draws.

Two wirings: ArduPilot with TELEM2 on the companion's UART and the GCS on its own link
(``uav-sitl vehicle --serial --gcs-port``: each link its own streams, as ArduPilot keeps them
per channel; socat joins the vehicle's pty to the companion's), and PX4 with the companion
and the GCS on one link (socat bridges the companion's pty to the vehicle's UDP port, as a
router sharing one TELEM port would): there the GCS sees the companion's stream requests
act, e.g. ``RC_CHANNELS = 0``.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from sitl.fleet_config import free_port
from tests.autopilot_checks import (
    AP_GUIDED,
    PX4_MISSION,
    Autopilot,
    check_first_fix_and_home,
    check_mission_upload_download,
    m,
)
from tests.companion_process import console_script, station_api
from tests.station_process import Station, running_station

ROOT = Path(__file__).resolve().parents[2]
SOCAT = shutil.which("socat")
pytestmark = pytest.mark.skipif(SOCAT is None, reason="socat is not installed (apt-get install "
                                "socat; `make test` as root installs it): it makes the pty pair "
                                "that stands in for the serial cable")


def _cable(tty: Path, vehicle_end: str) -> subprocess.Popen[bytes]:
    """A serial cable: a pty at ``tty`` (57600 baud, raw) joined to ``vehicle_end`` (socat's
    address of the vehicle's own pty, or of its UDP port)."""
    proc = subprocess.Popen([str(SOCAT), f"PTY,link={tty},raw,echo=0,b57600", vehicle_end],
                            stderr=subprocess.PIPE)
    deadline = time.monotonic() + 10
    while not tty.exists():
        assert proc.poll() is None and time.monotonic() < deadline, "socat made no pty"
        time.sleep(0.05)
    return proc


def _unplug(cable: subprocess.Popen[bytes]) -> None:
    cable.send_signal(signal.SIGTERM)
    cable.wait(timeout=10)


def _companion_config(tmp: Path, tty: Path, gs_port: int, keys: Path) -> Path:
    """``examples/companion.toml`` as a user edits it for a UART, plus this run's ports."""
    text = (ROOT / "examples" / "companion.toml").read_text()
    for old, new in {
        'url = "udpin:127.0.0.1:14550"': f'url = "{tty}"',
        "baud = 115200": "baud = 57600",
        "width = 640": "width = 320", "height = 480": "height = 240",
        "rate_hz = 5.0": "rate_hz = 1.0",
        "port = 14600": f"port = {gs_port}",
        '# fleet_key_file = "/etc/uav-companion/fleet.key"':
            f'fleet_key_file = "{keys / "fleet.key"}"',
        '# command_public_key_file = "/etc/uav-companion/command.pub"':
            f'command_public_key_file = "{keys / "command.pub"}"',
        # PX4 streams RC_CHANNELS unasked: the companion turns it off, as a user turns off
        # PX4's high-rate onboard streams
        "ESTIMATOR_STATUS = 1.0": "ESTIMATOR_STATUS = 1.0\nRC_CHANNELS = 0",
    }.items():
        assert text.count(old) == 1, f"examples/companion.toml no longer has {old!r}"
        text = text.replace(old, new)
    path = tmp / "companion.toml"
    path.write_text(text)
    return path


@dataclass
class Flight:
    station: Station
    companion: subprocess.Popen[bytes]
    companion_log: Path
    gcs: Autopilot
    tty: Path
    vehicle_end: str
    cable: subprocess.Popen[bytes]
    shared_link: bool

    def tile(self) -> dict[str, Any]:
        fleet = station_api(f"http://127.0.0.1:{self.station.port}", self.station.token,
                            "GET", "/api/fleet")
        tiles = [t for t in fleet["drones"] if t["drone"] == "drone1"]
        return dict(tiles[0]) if tiles else {}

    def until(self, what: str, predicate: Callable[[dict[str, Any]], bool],
              timeout_s: float) -> dict[str, Any]:
        """Poll the tile (the GCS keeps beating, as QGC does) until ``predicate`` holds."""
        deadline = time.monotonic() + timeout_s
        next_beat = 0.0
        while True:
            assert self.companion.poll() is None, self.log()[-3000:]
            if time.monotonic() >= next_beat:
                self.gcs.beat()
                next_beat = time.monotonic() + 1.0
            tile = self.tile()
            if tile and predicate(tile):
                return tile
            if time.monotonic() > deadline:
                raise AssertionError(f"{what}: not within {timeout_s:g} s; the tile: "
                                     f"{ {k: tile.get(k) for k in SHOWN} }\n{self.log()[-2000:]}")
            time.sleep(0.2)

    def log(self) -> str:
        return self.companion_log.read_text(errors="replace")


SHOWN = ("mode", "armed", "gps_fix", "battery", "autopilot_connected", "stale", "alt_m")


def _fresh_position(tile: dict[str, Any]) -> bool:
    return tile.get("lat_deg") is not None and "position" not in tile["stale"]


@pytest.fixture(params=["ardupilot-own-link", "px4-shared-link"])
def flight(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Flight]:
    flavour = str(request.param).split("-")[0]
    shared = str(request.param).endswith("shared-link")
    with running_station(tmp_path) as station:
        gs_port = int(re.findall(r"receiving fleet \d+ on udp://127.0.0.1:(\d+)",
                                 station.log_text())[0])
        vehicle_port = free_port()
        fc = tmp_path / "fc"  # the vehicle's own serial port (--serial-link)
        link = (["--port", str(vehicle_port)] if shared else
                ["--serial", "--serial-link", str(fc), "--baud", "57600", "--gcs-port",
                 str(vehicle_port)])
        # The fix 6 simulated s after each boot; a reboot silent for 2 s, as ArduCopter 4.5
        # SITL's (docs/companion.md): shorter than the companion's 3 s heartbeat timeout.
        vehicle = subprocess.Popen(
            [console_script("uav-sitl"), "vehicle", "--flavour", flavour, *link,
             "--first-fix", "6", "--reboot-s", "2", "--pattern", "orbit"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        assert vehicle.stdout is not None
        ready = vehicle.stdout.readline()
        assert ready.startswith("READY "), vehicle.communicate()[1][-2000:]
        tty = tmp_path / "ttyAMA0"
        vehicle_end = (f"UDP:127.0.0.1:{vehicle_port}" if shared
                       else f"GOPEN:{fc},raw,echo=0")
        cable = _cable(tty, vehicle_end)
        config = _companion_config(tmp_path, tty, gs_port, tmp_path / "data" / "keys")
        log = tmp_path / "companion.log"
        with open(log, "wb") as out:
            companion = subprocess.Popen(
                [console_script("uav-companion"), "--log-format", "text", "run", "--config",
                 str(config)], stdout=out, stderr=subprocess.STDOUT,
                env={**os.environ, "PYTHONUNBUFFERED": "1"})
        gcs = Autopilot.connect(f"udpout:127.0.0.1:{vehicle_port}")
        try:
            flight = Flight(station, companion, log, gcs, tty, vehicle_end, cable, shared)
            yield flight
        finally:
            gcs.conn.close()
            for proc in (companion, flight.cable, cable, vehicle):
                if proc.poll() is None:
                    proc.terminate()
            for proc in (companion, flight.cable, cable, vehicle):
                try:
                    proc.wait(timeout=20)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
            assert companion.returncode == 0, log.read_text(errors="replace")[-3000:]
            assert "Traceback" not in log.read_text(errors="replace")


@pytest.mark.timeout(240)
def test_a_serial_flight_with_a_gcs_a_pulled_cable_and_a_reboot(flight: Flight) -> None:
    gcs = flight.gcs
    ardupilot = gcs.ardupilot
    boot_mode = "STABILIZE" if ardupilot else "LOITER"
    first = flight.until("the first fix and position on the dashboard", lambda t: (
        t["autopilot_connected"] and t["mode"] == boot_mode and t["gps_fix"] == 3
        and t["armed"] is False and t["battery"] is not None and _fresh_position(t)), 120)
    assert abs(first["lat_deg"] - 47.397742) < 1e-3, first
    # The GCS asks for its streams (ArduPilot sends none on a link until asked), reads
    # parameters and uploads a mission (and reads it back), as QGC does.
    gcs.request_streams(4.0)
    assert gcs.param("SYSID_THISMAV" if ardupilot else "MAV_SYS_ID") == 1
    check_first_fix_and_home(gcs, timeout_s=30)
    check_mission_upload_download(gcs, north_m=20.0, alt_m=10.0)

    # The GCS changes the mode and arms: the dashboard follows within 2 s of the HEARTBEAT.
    gcs.set_mode(AP_GUIDED if ardupilot else PX4_MISSION)
    flight.until("the GCS's mode", lambda t: t["mode"] == ("GUIDED" if ardupilot
                                                            else "MISSION"), 2.5)
    assert gcs.command(m.MAV_CMD_COMPONENT_ARM_DISARM, 1) == m.MAV_RESULT_ACCEPTED
    gcs.heartbeat(gcs.armed, 5, "armed")
    flight.until("armed", lambda t: t["armed"] is True, 2.5)
    if not flight.shared_link:
        # The GCS stops every stream of its link (REQUEST_DATA_STREAM ALL, stop): the
        # companion's link streams on, as ArduPilot keeps rates per channel.
        gcs.conn.mav.request_data_stream_send(gcs.sysid, 1, m.MAV_DATA_STREAM_ALL, 0, 0)
        time.sleep(4.0)  # longer than the companion's 3 s stream-silence check
        tile = flight.until("positions still fresh", _fresh_position, 1)
        assert tile["ages"]["position"] < 2.0, tile
        assert "none of the requested streams" not in flight.log()

    # The cable is pulled mid-flight: unknown, not the last values, then back as it is.
    _unplug(flight.cable)
    assert not flight.tty.exists(), "socat removes the pty's link when it ends"
    flight.until("the link lost", lambda t: t["autopilot_connected"] is False
                 and (t["mode"], t["armed"], t["gps_fix"]) == (None, None, None), 6)
    flight.cable = _cable(flight.tty, flight.vehicle_end)
    flight.until("the link back with the truth", lambda t: t["autopilot_connected"]
                 and t["armed"] is True and t["gps_fix"] == 3 and _fresh_position(t), 10)

    # Disarmed, the GCS reboots the autopilot: 2 s of silence, under the heartbeat
    # timeout, so the link never looks lost. The rebooted autopilot is a new one (boot
    # mode, no EKF origin yet, streams at their defaults) and the dashboard must say so.
    assert gcs.command(m.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196) == m.MAV_RESULT_ACCEPTED
    flight.until("disarmed", lambda t: t["armed"] is False, 5)
    assert gcs.command(m.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 1) == m.MAV_RESULT_ACCEPTED
    booted = time.time() + 2.0  # the vehicle's silence
    flight.until("the boot mode after the reboot", lambda t: t["mode"] == boot_mode, 8)
    # ArduPilot streams nothing until asked again: positions stopped for good before, the
    # last one struck through on the dashboard for the rest of the flight.
    flight.until("positions from the new boot", lambda t: t["gps_fix"] == 3
                 and _fresh_position(t) and t["t"] - t["ages"]["position"] > booted, 25)
    if flight.shared_link:
        # PX4 streams its defaults again after a boot: the companion's "RC_CHANNELS = 0"
        # must be asked for again (it was: 5 Hz of RC_CHANNELS forever on a 57600 line).
        gcs.collect(2.0)  # what waited in the GCS's socket since the reboot
        assert gcs.collect(3.0)["RC_CHANNELS"] == 0
    log = flight.log()  # and the operator's journal says why
    assert "autopilot rebooted" in log or "none of the requested streams" in log, log
