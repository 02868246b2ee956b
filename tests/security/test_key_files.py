"""Secret key files others may read are refused, by both console scripts, with one line on
stderr and exit 2 (like ssh with a private key of mode 0644); wrong contents likewise, and a
key file of another kind than its setting names (keygen's files say which they are)."""

from __future__ import annotations

import base64
import subprocess
import sys
from pathlib import Path

import pytest

from tests.keys import write_test_keys

BIN = Path(sys.executable).parent


def _run(*argv: str) -> subprocess.CompletedProcess[str]:
    tool = BIN / argv[0]
    if not tool.exists():
        pytest.skip(f"{argv[0]} is not installed in this environment (pip install -e .)")
    return subprocess.run([str(tool), *argv[1:]], capture_output=True, text=True, timeout=60)


def _run_station(tmp_path: Path, config_text: str) -> subprocess.CompletedProcess[str]:
    """``uav-ground-station run`` on ``config_text`` (keys under ``tmp_path/keys``)."""
    config = tmp_path / "gs.toml"
    config.write_text(config_text)
    return _run("uav-ground-station", "run", "--config", str(config), "--data-dir",
                str(tmp_path / "data"), "--udp-port", "0", "--http-port", "0")


def _one_line_error(result: subprocess.CompletedProcess[str], fragment: str) -> None:
    assert result.returncode == 2, (result.returncode, result.stderr)
    assert "Traceback" not in result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, result.stderr
    assert fragment in lines[0], lines[0]


@pytest.mark.parametrize(("name", "key"), [("fleet.key", "fleet_key_file"),
                                           ("command.key", "command_key_file")])
def test_station_refuses_a_key_others_can_read(tmp_path: Path, name: str, key: str) -> None:
    keys = write_test_keys(tmp_path / "keys")
    (keys / name).chmod(0o644)
    result = _run_station(tmp_path, '[ground_station]\nfleet_key_file = "keys/fleet.key"\n'
                          'command_key_file = "keys/command.key"\n')
    _one_line_error(result, f"has mode 0644: others may read it (chmod 600 {keys / name})")
    assert key in result.stderr


def test_station_refuses_keys_others_can_read_in_the_data_dir(tmp_path: Path) -> None:
    keys = write_test_keys(tmp_path / "data" / "keys")
    (keys / "command.key").chmod(0o640)
    result = _run("uav-ground-station", "run", "--data-dir", str(tmp_path / "data"),
                  "--udp-port", "0", "--http-port", "0")
    _one_line_error(result, "has mode 0640: others may read it")


def test_companion_refuses_a_fleet_key_others_can_read(tmp_path: Path) -> None:
    keys = write_test_keys(tmp_path / "keys")
    (keys / "fleet.key").chmod(0o604)
    config = tmp_path / "companion.toml"
    config.write_text('[drone]\nid = "d1"\n[ground_station]\nfleet_key_file = "keys/fleet.key"\n'
                      'command_public_key_file = "keys/command.pub"\n')
    result = _run("uav-companion", "check", "--config", str(config), "--skip-mavlink",
                  "--skip-camera")
    _one_line_error(result, "ground_station.fleet_key_file: expected a key file only its owner")


@pytest.mark.parametrize(("content", "fragment"), [
    (b"short\n", "fleet_key"),
    (b"", "fleet_key"),
])
def test_station_refuses_a_fleet_key_of_the_wrong_length(tmp_path: Path, content: bytes,
                                                         fragment: str) -> None:
    keys = write_test_keys(tmp_path / "keys")
    (keys / "fleet.key").write_bytes(content)
    result = _run_station(tmp_path, '[ground_station]\nfleet_key_file = "keys/fleet.key"\n'
                          'command_key_file = "keys/command.key"\n')
    _one_line_error(result, fragment)


def test_station_refuses_a_command_key_of_the_wrong_length(tmp_path: Path) -> None:
    keys = write_test_keys(tmp_path / "keys")
    (keys / "command.key").write_bytes(b"QUJD\n")  # base64 of 3 bytes
    result = _run_station(tmp_path, '[ground_station]\nfleet_key_file = "keys/fleet.key"\n'
                          'command_key_file = "keys/command.key"\n')
    _one_line_error(result, "command_key_file")


@pytest.mark.parametrize("text", ['[ground_station]\nbogus = 1\n', "[ground_station\n",
                                  '[ground_station]\nhttp_port = "x"\n'])
def test_station_bad_config_is_one_line(tmp_path: Path, text: str) -> None:
    config = tmp_path / "gs.toml"
    config.write_text(text)
    result = _run("uav-ground-station", "run", "--config", str(config), "--data-dir",
                  str(tmp_path / "data"))
    _one_line_error(result, str(config))


def _keygen(tmp_path: Path) -> Path:
    made = _run("uav-ground-station", "keygen", "--out", str(tmp_path / "keys"))
    assert made.returncode == 0, made.stderr
    return tmp_path / "keys"


def _companion_check(tmp_path: Path, fleet: str, public: str) -> subprocess.CompletedProcess[str]:
    config = tmp_path / "companion.toml"
    config.write_text(f'[drone]\nid = "d1"\n[ground_station]\nfleet_key_file = "keys/{fleet}"\n'
                      f'command_public_key_file = "keys/{public}"\n')
    return _run("uav-companion", "check", "--config", str(config), "--skip-mavlink",
                "--skip-camera")


def test_keygen_names_the_kind_of_each_key(tmp_path: Path) -> None:
    keys = _keygen(tmp_path)
    assert (keys / "fleet.key").read_text().startswith("uav-infodist fleet key (")
    assert (keys / "command.key").read_text().startswith("uav-infodist command key (")
    assert (keys / "command.pub").read_text().startswith("uav-infodist command public key (")
    assert all(len((keys / n).read_text().splitlines()) == 1
               for n in ("fleet.key", "command.key", "command.pub"))
    ok = _companion_check(tmp_path, "fleet.key", "command.pub")
    assert ok.returncode == 0 and "check: ok" in ok.stdout, ok.stdout + ok.stderr


def test_companion_refuses_the_stations_private_key_as_its_public_key(tmp_path: Path) -> None:
    """The station's command.key as command_public_key_file passed `check` and dropped every
    command at run time without a word (all three files were bare base64 of 32 bytes)."""
    _keygen(tmp_path)
    result = _companion_check(tmp_path, "fleet.key", "command.key")
    _one_line_error(result, "ground_station.command_public_key_file: keys/command.key is the "
                            "ground station's PRIVATE command key")
    assert "copy command.pub to the drone, and never command.key" in result.stderr


@pytest.mark.parametrize(("fleet", "public", "fragment"), [
    ("fleet.key", "fleet.key", "command_public_key_file: keys/fleet.key is the fleet key"),
    ("command.pub", "command.pub",
     "fleet_key_file: keys/command.pub is the ground station's command public key"),
    ("command.key", "command.pub",
     "fleet_key_file: keys/command.key is the ground station's PRIVATE command key"),
])
def test_companion_refuses_a_key_file_of_another_kind(tmp_path: Path, fleet: str, public: str,
                                                     fragment: str) -> None:
    _keygen(tmp_path)
    _one_line_error(_companion_check(tmp_path, fleet, public), fragment)


def test_companion_refuses_an_untagged_fleet_key_as_its_public_key(tmp_path: Path) -> None:
    """Bare files (keygen before the kinds) still work, and look alike: the fleet key given as
    the command public key is told by its value."""
    keys = write_test_keys(tmp_path / "keys", fleet_key=base64.b64encode(bytes(range(32))))
    assert _companion_check(tmp_path, "fleet.key", "command.pub").returncode == 0
    (keys / "other.pub").write_bytes((keys / "fleet.key").read_bytes())
    result = _companion_check(tmp_path, "fleet.key", "other.pub")
    _one_line_error(result, "keys/other.pub is the same key as ground_station.fleet_key_file")


@pytest.mark.parametrize(("fleet", "command", "fragment"), [
    ("fleet.key", "command.pub",
     "'command_key_file': keys/command.pub is the ground station's command public key"),
    ("fleet.key", "fleet.key", "'command_key_file': keys/fleet.key is the fleet key"),
    ("command.key", "command.key",
     "'fleet_key_file': keys/command.key is the ground station's PRIVATE command key"),
])
def test_station_refuses_a_key_file_of_another_kind(tmp_path: Path, fleet: str, command: str,
                                                   fragment: str) -> None:
    _keygen(tmp_path)
    result = _run_station(tmp_path, f'[ground_station]\nfleet_key_file = "keys/{fleet}"\n'
                          f'command_key_file = "keys/{command}"\n')
    _one_line_error(result, fragment)


def test_station_refuses_an_untagged_command_key_as_its_fleet_key(tmp_path: Path) -> None:
    keys = write_test_keys(tmp_path / "keys")
    result = _run_station(tmp_path, '[ground_station]\nfleet_key_file = "keys/command.key"\n'
                          'command_key_file = "keys/command.key"\n')
    _one_line_error(result, "the fleet key is the same key as the command key")
    assert (keys / "command.key").exists()
