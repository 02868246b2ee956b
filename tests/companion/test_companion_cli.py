"""``uav-companion`` as a real subprocess: check, install-service, configuration errors."""

from __future__ import annotations

import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from companion_fake_vehicle import FakeVehicle

from companion.service import UNIT_NAME, install_service, unit_text
from tests.keys import write_test_keys

SCRIPT = Path(sys.executable).parent / "uav-companion"
COMMAND = [str(SCRIPT)] if SCRIPT.exists() else [sys.executable, "-m", "companion.cli"]


def _cli(*args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*COMMAND, "--log-format", "text", *args], capture_output=True,
                          text=True, timeout=timeout, check=False)


def _config(tmp_path: Path, url: str, camera: str, *, keys: bool = True,
            host: str = "127.0.0.1") -> Path:
    path = tmp_path / "companion.toml"
    key_lines = ""
    if keys:
        write_test_keys(tmp_path / "keys")
        key_lines = (f'[ground_station]\nhost = "{host}"\nfleet_key_file = "keys/fleet.key"\n'
                     'command_public_key_file = "keys/command.pub"\n')
    path.write_text(f'[drone]\nid = "d1"\n[mavlink]\nurl = "{url}"\n'
                    f'[camera]\nsource = "{camera}"\n[constraint]\nname = "constant"\n'
                    f'params = {{ limit_bytes_per_s = 20000.0 }}\n{key_lines}')
    return path


@pytest.fixture
def frames(tmp_path: Path) -> Path:
    folder = tmp_path / "frames"
    folder.mkdir()
    cv2.imwrite(str(folder / "a.png"), np.zeros((240, 320, 3), np.uint8))
    return folder


def test_check_reports_vehicle_and_camera(vehicle: FakeVehicle, tmp_path: Path,
                                          frames: Path) -> None:
    config = _config(tmp_path, f"udpout:127.0.0.1:{vehicle.port}", str(frames))
    result = _cli("check", "--config", str(config), "--timeout", "10")
    assert result.returncode == 0, result.stderr
    out = result.stdout
    assert "ardupilot autopilot" in out and "mode STABILIZE" in out
    assert "position 50.06" in out and "battery 12.30 V, 87 %" in out
    assert f"camera: folder:{frames}: frame 320x240" in out
    assert "mission spec: utility_specs/missions/image_streaming.toml" in out
    assert "keys: fleet key and the ground station's command key loaded" in out
    assert out.rstrip().endswith("check: ok")


def test_check_refuses_what_run_refuses_without_keys(tmp_path: Path, frames: Path) -> None:
    config = _config(tmp_path, "udpout:127.0.0.1:9", str(frames), keys=False)
    result = _cli("check", "--config", str(config), "--skip-mavlink", "--skip-camera")
    assert result.returncode == 2
    assert "`uav-ground-station keygen --out keys`" in result.stderr
    assert "Traceback" not in result.stderr


def test_check_says_when_the_vehicle_has_no_valid_position(tmp_path: Path,
                                                           frames: Path) -> None:
    vehicle = FakeVehicle(fix_after_s=600.0).start()  # ArduPilot after boot: 0/0, no origin
    try:
        config = _config(tmp_path, f"udpout:127.0.0.1:{vehicle.port}", str(frames))
        result = _cli("check", "--config", str(config), "--timeout", "10", "--skip-camera")
    finally:
        vehicle.stop()
    assert result.returncode == 0, result.stderr
    assert "mavlink: no valid position yet: no 3-D GPS fix (fix_type 1) (no geotags until " \
           "there is one)" in result.stdout
    assert "position 0.0" not in result.stdout


def test_check_without_vehicle_fails_with_reason(tmp_path: Path, frames: Path) -> None:
    config = _config(tmp_path, "udpout:127.0.0.1:9", str(frames))
    result = _cli("check", "--config", str(config), "--timeout", "1", "--skip-camera")
    assert result.returncode == 1
    assert "no autopilot HEARTBEAT within 1 s" in result.stdout


def test_check_logs_lines_a_person_reads_by_default(tmp_path: Path, frames: Path) -> None:
    """`check` is read at a terminal: its log lines are text, not the JSON objects `run`
    writes for journald (a newcomer's README walk saw one between check's lines)."""
    config = _config(tmp_path, "udpout:127.0.0.1:9", str(frames))
    result = subprocess.run([*COMMAND, "check", "--config", str(config), "--timeout", "1",
                             "--skip-camera"], capture_output=True, text=True, timeout=60,
                            check=False)
    assert result.returncode == 1 and "no autopilot HEARTBEAT within 1 s" in result.stdout
    log = result.stderr.splitlines()
    assert any(" INFO companion.mavlink: mavlink connection opened: udpout:127.0.0.1:9" in line
               for line in log), result.stderr
    assert not any(line.startswith("{") for line in log), result.stderr


def test_check_names_the_program_that_shares_its_port(tmp_path: Path, frames: Path) -> None:
    """A program bound to 127.0.0.1:P with SO_REUSEADDR (as every pymavlink one is) gets
    what the vehicle sends to 127.0.0.1:P, and our udpin:0.0.0.0:P binds all the same: check
    said "nothing sent MAVLink to 0.0.0.0:P" while the vehicle was sending (seen on the
    shared test machine, another companion on 14550)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as other:
        other.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        other.bind(("127.0.0.1", 0))
        port = other.getsockname()[1]
        config = _config(tmp_path, f"udpin:0.0.0.0:{port}", str(frames))
        result = _cli("check", "--config", str(config), "--timeout", "1", "--skip-camera")
    assert result.returncode == 1
    assert (f"no autopilot HEARTBEAT within 1 s (another program also listens on "
            f"127.0.0.1:{port} and gets the datagrams sent there") in result.stdout, result.stdout
    alone = _cli("check", "--config", str(config), "--timeout", "1", "--skip-camera")
    assert f"(nothing sent MAVLink to 0.0.0.0:{port}:" in alone.stdout, alone.stdout


def test_check_names_a_ground_station_host_that_does_not_resolve(tmp_path: Path,
                                                                 frames: Path) -> None:
    """It said `check: ok`, and `run` then died of a 40-line gaierror traceback."""
    config = _config(tmp_path, "udpout:127.0.0.1:9", str(frames), host="no.such.host.invalid")
    result = _cli("check", "--config", str(config), "--skip-mavlink", "--skip-camera")
    assert result.returncode == 1, result.stdout + result.stderr
    assert "ground station: ground_station.host 'no.such.host.invalid' does not resolve (" \
        in result.stdout.splitlines()[-2], result.stdout
    assert result.stdout.rstrip().endswith("check: 1 problem(s)")
    assert "Traceback" not in result.stderr


def test_run_warns_of_a_ground_station_host_that_does_not_resolve(tmp_path: Path) -> None:
    """A drone that boots before its DNS keeps running (MAVLink, camera, mission log) and
    says once which setting does not resolve, instead of dying of an ExceptionGroup."""
    config = _config(tmp_path, "udpout:127.0.0.1:9", "synthetic", host="no.such.host.invalid")
    proc = subprocess.Popen([*COMMAND, "--log-format", "text", "run", "--config", str(config)],
                            stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
    try:
        assert proc.stderr is not None
        for line in proc.stderr:
            if "does not resolve" in line or "companion failed" in line:
                break
        time.sleep(1.0)
        assert proc.poll() is None, "the companion stopped"
    finally:
        proc.send_signal(signal.SIGTERM)
        _, rest = proc.communicate(timeout=30)
    assert proc.returncode == 0, rest
    assert " WARNING companion.transport: ground_station.host 'no.such.host.invalid' does not " \
        "resolve (" in line and "retrying every 5 s" in line, line
    assert "Traceback" not in rest and "companion failed" not in rest


def test_bad_config_exits_2_naming_file_and_key(tmp_path: Path) -> None:
    path = tmp_path / "bad.toml"
    path.write_text('[drone]\nid = "d1"\n[camera]\nrate_hz = 0\n')
    result = _cli("check", "--config", str(path))
    assert result.returncode == 2
    assert f"{path}: camera.rate_hz: expected a number > 0, got 0" in result.stderr


def test_run_with_a_camera_that_cannot_open_exits_2_in_one_line(tmp_path: Path) -> None:
    """A bad camera.source is a setup error like any other, not a traceback."""
    camera = "/no/such/video.mp4"
    why = ("not 'synthetic', a device, a GStreamer pipeline, a URL, a folder or an existing "
           "video file")
    config = _config(tmp_path, "udpin:127.0.0.1:14599", camera)
    result = _cli("run", "--config", str(config), timeout=120)
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    assert f"cannot start: {config}: camera.source: camera source {camera!r}: {why}" \
        in result.stderr.splitlines()


def test_bad_constraint_is_caught_by_check(tmp_path: Path) -> None:
    path = tmp_path / "c.toml"
    path.write_text('[drone]\nid = "d1"\n[constraint]\nname = "magic"\n')
    result = _cli("check", "--config", str(path), "--skip-mavlink", "--skip-camera")
    assert result.returncode == 2
    assert "constraint" in result.stderr and "magic" in result.stderr


def test_install_service_dry_run_and_unit_dir(tmp_path: Path) -> None:
    config = tmp_path / "companion.toml"  # a config run accepts (keys set): see the audit's
    write_test_keys(tmp_path / "keys")    # tests/integration/test_cli_bad_input_audit.py
    config.write_text('[drone]\nid = "d1"\n[ground_station]\nfleet_key_file = "keys/fleet.key"'
                      '\ncommand_public_key_file = "keys/command.pub"\n')
    dry = _cli("install-service", "--config", str(config), "--dry-run")
    assert dry.returncode == 0
    assert "Restart=on-failure" in dry.stdout and f"run --config {config}" in dry.stdout
    assert "# would run: systemctl enable --now uav-companion.service" in dry.stdout
    unit_dir = tmp_path / "units"
    written = _cli("install-service", "--config", str(config), "--unit-dir", str(unit_dir),
                   "--no-enable")
    assert written.returncode == 0, written.stderr
    text = (unit_dir / UNIT_NAME).read_text()
    assert "Restart=on-failure" in text and "WantedBy=multi-user.target" in text


def test_install_service_enables_through_systemctl(tmp_path: Path) -> None:
    calls: list[tuple[str, ...]] = []

    def runner(argv: object) -> int:
        calls.append(tuple(argv))  # type: ignore[arg-type]
        return 0

    result = install_service(config_path=tmp_path / "c.toml", unit_dir=tmp_path, runner=runner)
    assert result.written and calls == [("systemctl", "daemon-reload"),
                                        ("systemctl", "enable", "--now", UNIT_NAME)]
    with pytest.raises(RuntimeError, match="daemon-reload failed with exit status 1"):
        install_service(config_path=tmp_path / "c.toml", unit_dir=tmp_path,
                        runner=lambda argv: 1)


def test_unit_text_quotes_paths_and_sets_user() -> None:
    text = unit_text(config_path=Path("/etc/my dir/c.toml"), exec_argv=["/usr/bin/uav-companion"],
                     user="pi")
    assert "ExecStart=/usr/bin/uav-companion run --config '/etc/my dir/c.toml'" in text
    assert "User=pi" in text and "SupplementaryGroups=dialout video" in text
    # numba's cache: systemd creates %C/uav-companion for the service user
    assert "CacheDirectory=uav-companion" in text
    assert "Environment=NUMBA_CACHE_DIR=%C/uav-companion" in text


def test_the_unit_runs_the_companion_with_least_privilege(tmp_path: Path) -> None:
    """It ran as root with every privilege, and a configuration error restarted every 2 s."""
    text = unit_text(config_path=Path("/etc/uav-companion/config.toml"),
                     exec_argv=["/usr/bin/uav-companion"], user="pi",
                     writable=[Path("/srv/uav logs")])
    lines = text.splitlines()
    for directive in ("NoNewPrivileges=yes", "ProtectSystem=full", "ProtectHome=read-only",
                      "PrivateTmp=yes", "RestrictSUIDSGID=yes", "RestartPreventExitStatus=2",
                      "StateDirectory=uav-companion"):
        assert directive in lines, directive
    assert "ReadWritePaths='-/srv/uav logs'" in lines
    # the autopilot's UART and the camera stay reachable: nothing that narrows /dev
    assert not any(line.startswith(("PrivateDevices", "DevicePolicy", "DeviceAllow",
                                    "ProtectClock")) for line in lines)
    verify = shutil.which("systemd-analyze")
    if verify is None:
        pytest.skip("systemd-analyze not installed (apt install systemd) to check the unit")
    unit = tmp_path / UNIT_NAME
    unit.write_text(text)
    result = subprocess.run([verify, "verify", str(unit)], capture_output=True, text=True,
                            timeout=60, check=False)
    complaints = [line for line in (result.stdout + result.stderr).splitlines()
                  if str(unit) in line]  # not its words about the host's own units
    assert complaints == [], complaints


def test_structured_logs_are_one_json_object_per_line(
        capsys: pytest.CaptureFixture[str]) -> None:
    import json
    import logging

    from companion.cli import configure_logging

    configure_logging("info", "json")
    logging.getLogger("companion.test").info("link %s", "lost", extra={"event": "link"})
    record = json.loads(capsys.readouterr().err.strip().splitlines()[-1])
    assert record["msg"] == "link lost" and record["event"] == "link"
    assert record["level"] == "info" and record["logger"] == "companion.test"
    logging.getLogger().handlers.clear()
    logging.getLogger().setLevel(logging.WARNING)


def test_check_without_keys_never_says_ok_first(tmp_path: Path) -> None:
    """The example config as shipped (no key files): check printed "config: ...: ok" and then
    "configuration error: ... fleet_key_file is not set", which read as a contradiction."""
    config = _config(tmp_path, "udpin:127.0.0.1:1", "synthetic", keys=False)
    result = _cli("check", "--config", str(config), "--skip-mavlink", "--skip-camera")
    assert result.returncode == 2
    assert result.stdout == ""
    assert result.stderr.startswith(f"configuration error: {config}: "
                                    "ground_station.fleet_key_file is not set")


def test_install_service_checks_what_the_service_user_can_read(tmp_path: Path) -> None:
    """A key only root could read passed install-service --user; the service then failed at
    every start ("a readable key file (Permission denied)")."""
    import os
    import pwd
    import tempfile

    from companion.service import make_folder_for, unreadable_for

    try:
        nobody = pwd.getpwnam("nobody")
    except KeyError:
        pytest.skip("no user 'nobody' on this machine")
    open_dir = Path(tempfile.mkdtemp(dir="/tmp"))
    try:
        open_dir.chmod(0o755)
        key = open_dir / "fleet.key"
        key.write_text("k\n")
        key.chmod(0o600)
        problem = unreadable_for("nobody", [key])
        assert problem is not None and problem.startswith(f"user nobody cannot read {key} (")
        assert "mode 0600" in problem
        assert unreadable_for("root", [key]) is None
        key.chmod(0o644)
        assert unreadable_for("nobody", [key]) is None
        hidden = open_dir / "private"
        hidden.mkdir(mode=0o700)
        (hidden / "command.pub").write_text("p\n")
        problem = unreadable_for("nobody", [hidden / "command.pub"])
        assert problem is not None and f"({hidden}: owner uid" in problem
        if os.geteuid() == 0:  # the mission log's folder, made for the service's user
            make_folder_for("nobody", open_dir / "logs" / "uav")
            assert (open_dir / "logs" / "uav").stat().st_uid == nobody.pw_uid
            assert (open_dir / "logs").stat().st_uid == nobody.pw_uid
    finally:
        shutil.rmtree(open_dir)
