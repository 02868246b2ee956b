"""A serial autopilot link, end to end: ``uav-sitl vehicle --serial`` serves a vehicle on a
pseudo-terminal and the companion flies it through pymavlink's serial path (pyserial), the
way a Pixhawk on a Raspberry Pi's UART is wired. ``check`` names what is wrong plainly."""

from __future__ import annotations

import contextlib
import errno
import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import serial  # pyserial: a dependency, pymavlink's serial links import it
from test_companion_system import (  # type: ignore[import-not-found]
    Receiver,
    _write_config,
    receiver,  # noqa: F401 - fixture
)

from companion.mavlink import describe_connect_error
from tests.companion_process import start_companion, stop_companion, until
from tests.keys import write_test_keys

BIN = Path(sys.executable).parent
SITL = BIN / "uav-sitl"
COMPANION = BIN / "uav-companion"


def _serial_vehicle(link: Path, *args: str) -> tuple[subprocess.Popen[str], dict[str, object]]:
    # A fix at boot: this file tests the serial line, not the wait for a GPS fix.
    proc = subprocess.Popen([str(SITL), "vehicle", "--serial", "--serial-link", str(link),
                             "--first-fix", "0", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    line = proc.stdout.readline()
    if not line.startswith("READY "):
        proc.kill()
        pytest.fail(f"no READY line: {line!r} {proc.communicate()[1][-2000:]}")
    return proc, json.loads(line.removeprefix("READY "))


def _end(proc: subprocess.Popen[str]) -> str:
    proc.terminate()
    try:
        _, err = proc.communicate(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        _, err = proc.communicate()
    return err


def _check(config: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(COMPANION), "--log-format", "text", "check", "--config",
                           str(config), "--skip-camera", *extra], capture_output=True,
                          text=True, timeout=60, check=False)


def _mini_config(tmp_path: Path, url: str, *, baud: int = 115200) -> Path:
    # the keys `check` (like `run`) requires: there is no built-in one
    keys = write_test_keys(tmp_path / "keys")
    path = tmp_path / "c.toml"
    path.write_text(f'[drone]\nid = "d1"\n[mavlink]\nurl = "{url}"\nbaud = {baud}\n'
                    f'[ground_station]\nfleet_key_file = "{keys / "fleet.key"}"\n'
                    f'command_public_key_file = "{keys / "command.pub"}"\n')
    return path


@pytest.mark.timeout(120)
async def test_companion_flies_the_vehicle_over_a_pty_serial_line(
        receiver: tuple[Receiver, int], tmp_path: Path) -> None:  # noqa: F811
    rx, gs_port = receiver
    link = tmp_path / "ttyFC"
    vehicle, ready = _serial_vehicle(link, "--baud", "57600", "--flavour", "ardupilot",
                                     "--pattern", "orbit", "--autostart")
    try:
        assert ready["serial"] == str(link) and ready["baud"] == 57600
        assert str(ready["tty"]).startswith("/dev/pts/")
        assert os.path.realpath(link) == ready["tty"]
        assert "port" not in ready  # no UDP socket: the serial line is the only way in
        config = _write_config(tmp_path / "d1.toml", drone="d1", vehicle_port=0,
                               gs_port=gs_port, mavlink_url=str(link), frames=Path("synthetic"),
                               rate_hz=1.0, extra='[camera.options]\nscene = "demo"\n',
                               constraint='[constraint]\nname = "constant"\n'
                                          'params = { limit_bytes_per_s = 100000.0 }')
        # 57600 baud carries the heartbeat behind the requested streams: a loaded machine can
        # hold one back past the other tests' 1.5 s, so this line gets a real GCS's margin.
        config.write_text(config.read_text().replace("heartbeat_timeout_s = 1.5",
                                                     "baud = 57600\nheartbeat_timeout_s = 3.0", 1))
        assert "heartbeat_timeout_s = 3.0" in config.read_text()
        proc = start_companion(config, json_logs=True)
        try:
            # ArduPilot streams nothing on a link until asked: positions prove the companion's
            # stream requests went out over the line and the vehicle's telemetry came back.
            await until(lambda: len(rx.of("d1", "position")) >= 3, 60, proc)
            status = rx.of("d1", "status")[-1]
            assert status.data["autopilot"] == "ardupilot"
            first, last = rx.of("d1", "position")[0], rx.of("d1", "position")[-1]
            home_lat, home_lon = ready["home"][:2]  # type: ignore[index]
            assert abs(last.data["lat_deg"] - home_lat) < 0.01
            assert abs(last.data["lon_deg"] - home_lon) < 0.01
            # It flies its orbit (--autostart): the reported position moves. Armed at the
            # fix, it climbs straight up first, so the first few positions may share lat/lon.

            def moved() -> bool:
                latest = rx.of("d1", "position")[-1]
                return (latest.data["lat_deg"], latest.data["lon_deg"]) != \
                    (first.data["lat_deg"], first.data["lon_deg"])

            await until(moved, 60, proc)
            # The autopilot goes away (a USB cable pulled: the line hangs up, the device
            # node disappears) and comes back on the same path: the companion keeps running
            # and flies on without a restart.
            _end(vehicle)
            assert not link.exists(), "the vehicle removes its symlink when it stops"
            await until(lambda: rx.of("d1", "status")[-1].data["connected"] is False, 30,
                         proc)
            vehicle, _ = _serial_vehicle(link, "--baud", "57600", "--flavour", "ardupilot")
            seen = len(rx.of("d1", "position"))
            await until(lambda: len(rx.of("d1", "position")) > seen + 1
                         and rx.of("d1", "status")[-1].data["connected"] is True, 60, proc)
        finally:
            code, err = stop_companion(proc)
        assert code == 0, err[-3000:]
        assert err.count(f"mavlink connection opened: {link}") == 2, err[-3000:]
        assert "mavlink link lost" in err
        # said once while it retried every 0.2 s, not once per retry
        assert err.count(f"no such device {link}") == 1, err[-3000:]
    finally:
        _end(vehicle)


def test_check_names_another_program_reading_the_serial_port(tmp_path: Path) -> None:
    """MAVProxy started on the companion's UART too: two readers split the bytes, and the
    companion's reads fail ("readiness to read but returned no data") and lose the link."""
    from companion.mavlink_hint import other_openers

    link = tmp_path / "ttyS3"
    vehicle, _ = _serial_vehicle(link, "--flavour", "ardupilot")
    # it keeps the port open through the same split-read errors the companion sees: a reader
    # that died of one left the check nobody to name (seen once in a fresh-clone make test)
    reader = subprocess.Popen([sys.executable, "-c", "import serial, sys\n"
                               "s = serial.Serial(sys.argv[1], 57600, timeout=0.1)\n"
                               "while True:\n"
                               "    try:\n"
                               "        s.read(64)\n"
                               "    except serial.SerialException:\n"
                               "        pass\n", str(link)])
    try:
        deadline = time.monotonic() + 20
        while not other_openers(str(link)):
            assert time.monotonic() < deadline and reader.poll() is None
            time.sleep(0.05)
        result = _check(_mini_config(tmp_path, str(link)), "--timeout", "5")
    finally:
        reader.kill()
        reader.wait()
        _end(vehicle)
    # named, and only it: the vehicle holds the pty's master (the other end of the wire)
    assert (f"another program also has {link} open (pid {reader.pid}: python):"
            in result.stdout), result.stdout
    assert "Traceback" not in result.stderr


def test_check_says_a_line_of_noise_is_a_baud_rate_problem(tmp_path: Path) -> None:
    """The companion at 57600 and the autopilot's TELEM port at 115200: bytes arrive, no
    frame parses. It said "open but silent: check the wiring, ..." as for a dead line."""
    import threading
    import tty as termios_tty

    master, slave = os.openpty()
    termios_tty.setraw(slave)
    link = tmp_path / "ttyS4"
    link.symlink_to(os.ttyname(slave))
    stop = threading.Event()

    def noise() -> None:  # no MAVLink magic byte in it: nothing that could parse
        while not stop.wait(0.05):
            with contextlib.suppress(OSError):
                os.write(master, bytes(range(0x20, 0xE0)))

    threading.Thread(target=noise, daemon=True).start()
    try:
        result = _check(_mini_config(tmp_path, str(link), baud=57600), "--timeout", "2")
    finally:
        stop.set()
        os.close(master)
        os.close(slave)
    assert result.returncode == 1
    assert "bytes arrive but no MAVLink frame parses (" in result.stdout, result.stdout
    assert "the baud rate (57600) differs from the autopilot's" in result.stdout


def test_check_names_a_missing_serial_device(tmp_path: Path) -> None:
    device = tmp_path / "ttyAMA7"
    result = _check(_mini_config(tmp_path, str(device)), "--timeout", "2")
    assert result.returncode == 1
    assert (f"mavlink: {device}: cannot open: [Errno 2] no such device {device}: is the "
            "autopilot connected") in result.stdout
    assert "Traceback" not in result.stderr


@pytest.mark.skipif(os.geteuid() == 0, reason="root opens any device: run as a normal user "
                    "to test the permission message end to end (the unit test below covers it)")
def test_check_names_a_permission_problem(tmp_path: Path) -> None:
    link = tmp_path / "ttyS9"
    vehicle, ready = _serial_vehicle(link)
    try:
        os.chmod(str(ready["tty"]), 0o000)
        result = _check(_mini_config(tmp_path, str(link)), "--timeout", "2")
    finally:
        _end(vehicle)
    assert result.returncode == 1
    assert f"permission denied on {link}: add the user to the dialout group" in result.stdout


def test_pyserial_errors_are_described_plainly(tmp_path: Path) -> None:
    """The exceptions pyserial really raises, for the cases root cannot reproduce."""
    with pytest.raises(serial.SerialException) as missing:
        serial.Serial(str(tmp_path / "nothing"))
    assert describe_connect_error(str(tmp_path / "nothing"), missing.value).startswith(
        f"[Errno 2] no such device {tmp_path / 'nothing'}")
    denied = serial.SerialException(errno.EACCES, "could not open port /dev/serial0: "
                                    "[Errno 13] Permission denied: '/dev/serial0'")
    assert describe_connect_error("/dev/serial0,921600", denied) == (
        "[Errno 13] permission denied on /dev/serial0: add the user to the dialout group "
        "(sudo usermod -aG dialout $USER, then log in again)")
    plain_file = tmp_path / "file"
    plain_file.write_text("x")
    with pytest.raises(serial.SerialException) as not_tty:
        serial.Serial(str(plain_file))
    assert describe_connect_error(str(plain_file), not_tty.value) == \
        f"[Errno 25] {plain_file} is not a serial device"
    assert "pip install pyserial" in describe_connect_error(
        "/dev/serial0", ModuleNotFoundError("No module named 'serial'"))


def test_check_prints_address_in_use_plainly(tmp_path: Path) -> None:
    """Symptom 3 of issue 11: the cause was hidden in JSON warnings on stderr."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as busy:
        busy.bind(("127.0.0.1", 0))
        port = busy.getsockname()[1]
        result = _check(_mini_config(tmp_path, f"udpin:127.0.0.1:{port}"), "--timeout", "2")
    assert result.returncode == 1
    assert (f"mavlink: udpin:127.0.0.1:{port}: cannot open: [Errno 98] Address already in "
            f"use: another program already listens on 127.0.0.1:{port}") in result.stdout


def test_check_says_why_a_listening_link_stays_silent(tmp_path: Path) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    result = _check(_mini_config(tmp_path, f"udpin:127.0.0.1:{port}"), "--timeout", "1")
    assert result.returncode == 1
    assert (f"no autopilot HEARTBEAT within 1 s (nothing sent MAVLink to 127.0.0.1:{port}: "
            "point the autopilot's telemetry output") in result.stdout
