"""Configuration: the example parses; every error names file, key and expected value."""

from __future__ import annotations

from pathlib import Path

import pytest

from companion.config import ConfigError, load_config, missing_keys, parse_config
from companion.mavlink import DEFAULT_STREAM_RATES_HZ
from tests.keys import TEST_COMMAND_PUB, write_test_keys

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "companion.toml"


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "config.toml"
    path.write_text(text)
    return path


def test_example_config_is_valid_and_complete() -> None:
    config = load_config(EXAMPLE)
    assert config.drone_id == "drone1"
    assert config.mavlink.url == "udpin:127.0.0.1:14550"  # loopback (docs/security.md #20)
    assert config.mavlink.stream_rates_hz["ATTITUDE"] == 10.0
    assert config.camera.width == 640 and config.camera.rate_hz == 5.0
    assert config.camera.versions == ("full", "half", "quarter")
    assert config.scoring.scorers == ("red_share",)
    assert config.scoring.settings["red_share"].upper2 == (179, 255, 255)
    assert config.budgets.mcts_iterations == 300
    assert config.constraint.name == "adaptive"
    # no insecure default: the example names the key files but ships no key
    assert config.ground_station.fleet_key is None
    assert config.ground_station.command_public_key is None
    problem = missing_keys(config)
    assert problem is not None and "`uav-ground-station keygen --out keys`" in problem
    assert "\n" not in problem


def test_minimal_config_takes_defaults() -> None:
    config = parse_config({"drone": {"id": "d7"}})
    assert config.drone_id == "d7" and config.camera.source == "synthetic"
    assert config.mission.spec == "builtin:image_streaming"


@pytest.mark.parametrize(
    ("text", "key", "expected"),
    [
        ("[drone]\n", "drone.id", "a non-empty string"),
        ('[drone]\nid = "d"\n[camera]\nrate_hz = -1\n', "camera.rate_hz", "a number > 0"),
        ('[drone]\nid = "d"\n[camera]\nwidth = "wide"\n', "camera.width", "an integer in"),
        ('[drone]\nid = "d"\n[camera]\nfps = 3\n', "camera.fps", "one of"),
        ('[drone]\nid = "d"\n[camera]\nversions = ["huge"]\n', "camera.versions",
         "a non-empty list of full | half | quarter"),
        ('[drone]\nid = "d"\n[scoring]\nscorers = ["yolo"]\n', "scoring.scorers", "a list of"),
        ('[drone]\nid = "d"\n[scoring.red_share]\nlower1 = [0, 300, 0]\n',
         "scoring.red_share.lower1", "[H 0..179"),
        ('[drone]\nid = "d"\n[mavlink]\nstream_rates_hz = { FOO = 1 }\n',
         "mavlink.stream_rates_hz", "a table of MAVLink message names"),
        ('[drone]\nid = "d"\n[ground_station]\nport = 70000\n', "ground_station.port",
         "an integer in 1..65535"),
        ('[drone]\nid = "d"\n[ground_station]\nfleet_key = "short"\n',
         "ground_station.fleet_key", "at least 16 bytes"),
        ('[drone]\nid = "d"\n[budgets]\nmcts_iterations = true\n', "budgets.mcts_iterations",
         "an integer"),
        ('[drone]\nid = "d"\n[telemetry]\nposition_rate_hz = -2\n',
         "telemetry.position_rate_hz", "a number >= 0"),
        ('[drone]\nid = "d"\n[colour]\nx = 1\n', "colour", "one of"),
        # a typo names the key it meant, not the value ("expected one of [...], got 'x'")
        ('[drone]\nid = "d"\n[mavlink]\nulr = "x"\n', "mavlink.ulr",
         "expected a known key (did you mean 'url'?), one of ['baud', "),
    ],
)
def test_errors_name_file_key_and_expectation(tmp_path: Path, text: str, key: str,
                                              expected: str) -> None:
    path = _write(tmp_path, text)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    message = str(info.value)
    assert message.startswith(f"{path}: {key}: expected ")
    assert expected in message


def test_missing_file_and_bad_toml(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="no such configuration file"):
        load_config(tmp_path / "absent.toml")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(_write(tmp_path, "[drone\n"))


def test_the_shipped_status_period_fits_the_stations_link_lost_s() -> None:
    """Before a position a hand-configured drone sends little but its status: every 5 s by
    default against the station's 3 s link_lost_s made the dashboard say "link lost: nothing
    heard for 3.8 s", then "link back", over and over on a healthy loopback link."""
    import tomllib

    from companion.config import TelemetryConfig
    from ground_station.config import GroundConfig

    station = tomllib.loads((EXAMPLE.parent / "ground_station.toml").read_text())
    lost_s = [GroundConfig().link_lost_s, station["ground_station"]["link_lost_s"]]
    periods = [TelemetryConfig().status_period_s, load_config(EXAMPLE).telemetry.status_period_s,
               parse_config({"drone": {"id": "d"}}).telemetry.status_period_s]
    assert 2.5 * max(periods) <= min(lost_s), (periods, lost_s)


def test_relative_paths_and_key_file(tmp_path: Path) -> None:
    (tmp_path / "fleet.key").write_bytes(b"0123456789abcdef-secret\n")
    (tmp_path / "fleet.key").chmod(0o600)  # a secret others may read is refused
    path = _write(tmp_path, '[drone]\nid = "d"\n[mission]\nspec = "spec.toml"\n'
                            'log = "logs/m.jsonl"\n[ground_station]\n'
                            'fleet_key_file = "fleet.key"\n')
    config = load_config(path)
    assert config.mission.spec == str(tmp_path / "spec.toml")
    assert config.mission.log == str(tmp_path / "logs" / "m.jsonl")
    assert config.ground_station.fleet_key == b"0123456789abcdef-secret"


def test_command_public_key_from_file_or_inline(tmp_path: Path) -> None:
    keys = write_test_keys(tmp_path / "keys")
    path = _write(tmp_path, '[drone]\nid = "d"\n[ground_station]\nfleet_key_file = '
                            '"keys/fleet.key"\ncommand_public_key_file = "keys/command.pub"\n')
    config = load_config(path)
    assert config.ground_station.command_public_key == TEST_COMMAND_PUB
    assert missing_keys(config) is None
    inline = (keys / "command.pub").read_text().strip()
    config = parse_config({"drone": {"id": "d"},
                           "ground_station": {"command_public_key": inline}})
    assert config.ground_station.command_public_key == TEST_COMMAND_PUB
    problem = missing_keys(config)
    assert problem is not None and "ground_station.fleet_key_file is not set" in problem


@pytest.mark.parametrize("text", ["not base64!", "AAAA"])
def test_bad_command_public_key(tmp_path: Path, text: str) -> None:
    path = _write(tmp_path, f'[drone]\nid = "d"\n[ground_station]\ncommand_public_key = "{text}"\n')
    with pytest.raises(ConfigError, match=r"ground_station.command_public_key: expected command"):
        load_config(path)


def test_unreadable_key_file(tmp_path: Path) -> None:
    path = _write(tmp_path, '[drone]\nid = "d"\n[ground_station]\nfleet_key_file = "nokey"\n')
    with pytest.raises(ConfigError, match=r"ground_station.fleet_key_file: expected a readable"):
        load_config(path)


def test_hog_people_settings_are_read_and_checked(tmp_path: Path) -> None:
    good = tmp_path / "good.toml"
    good.write_text('[drone]\nid = "d1"\n[scoring.hog_people]\nscale = 1.0\nwin_stride_px = 16\n')
    hog = load_config(good).scoring.settings["hog_people"]
    assert (hog.scale, hog.win_stride_px, hog.pyramid_scale) == (1.0, 16, 1.05)
    bad = tmp_path / "bad.toml"
    bad.write_text('[drone]\nid = "d1"\n[scoring.hog_people]\nwin_stride_px = 12\n')
    with pytest.raises(ConfigError, match="win_stride_px"):
        load_config(bad)


def test_a_short_stream_table_keeps_the_estimator_streams(tmp_path: Path) -> None:
    """Against ArduCopter 4.5 SITL, a table without EKF_STATUS_REPORT (the example's until
    round 12) had the companion send and geotag GPS positions for ~30 s while the EKF had no
    origin (CONST_POS_MODE): positions are judged by the estimator only if it is streamed."""
    config = load_config(_write(tmp_path, '[drone]\nid = "d"\n[mavlink.stream_rates_hz]\n'
                                          'GLOBAL_POSITION_INT = 2.0\nSYSTEM_TIME = 0\n'))
    rates = config.mavlink.stream_rates_hz
    assert rates["GLOBAL_POSITION_INT"] == 2.0
    assert rates["SYSTEM_TIME"] == 0.0  # listed as 0: off
    assert rates["EKF_STATUS_REPORT"] == 1.0 and rates["ESTIMATOR_STATUS"] == 1.0
    assert rates["ATTITUDE"] == 10.0  # unlisted: the default
    assert set(rates) == set(DEFAULT_STREAM_RATES_HZ)
    assert load_config(EXAMPLE).mavlink.stream_rates_hz["EKF_STATUS_REPORT"] == 1.0


def test_any_mavlink_message_can_be_turned_off(tmp_path: Path) -> None:
    """PX4's onboard link streams ~400 messages/s (real PX4 SIH, 2026-11-24), HIGHRES_IMU
    among them: a Raspberry Pi's user must be able to turn off what the companion does not
    use; a name that is no MAVLink message is still a config error."""
    from companion.mavlink_watch import streams_for

    config = load_config(_write(tmp_path, '[drone]\nid = "d"\n[mavlink.stream_rates_hz]\n'
                                          'HIGHRES_IMU = 0\nSCALED_IMU = 0\n'))
    rates = config.mavlink.stream_rates_hz
    assert rates["HIGHRES_IMU"] == 0.0 and rates["ATTITUDE"] == 10.0
    assert streams_for("px4", rates)["HIGHRES_IMU"] == 0.0  # asked for: interval -1, off
    for bad in ("highres_imu", "NO_SUCH_MESSAGE", "MAVLINK_MSG_ID_HEARTBEAT"):
        with pytest.raises(ConfigError, match="a table of MAVLink message names"):
            load_config(_write(tmp_path, f'[drone]\nid = "d"\n[mavlink.stream_rates_hz]\n'
                                         f'{bad} = 0\n'))


def test_example_shows_the_peers_table_with_its_defaults() -> None:
    """examples/companion.toml had no [peers] table (docs/peers.md's keys had no template:
    a user following the peer-sharing page by hand wrote it from the doc's snippet)."""
    import re

    from companion.peers import PeersSettings

    assert load_config(EXAMPLE).peers == PeersSettings()
    text = EXAMPLE.read_text()
    section = text[text.index("\n[peers]"):]
    named = set(re.findall(r"^(?:# )?([a-z_]+) = ", section, re.MULTILINE))
    assert named == set(PeersSettings.__dataclass_fields__), named
