"""Out-of-range numbers on `uav-sitl vehicle` and `uav-sitl camera` are usage errors, in process
(the subprocess cases of the same kind are in tests/integration/test_cli_bad_input.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

from sitl import camera_cli
from sitl.vehicle.cli import parse_args


@pytest.mark.parametrize(("argv", "message"), [
    (["--speed", "-1"], "--speed must be a finite number > 0, got -1.0"),
    (["--speed", "nan"], "--speed must be a finite number > 0, got nan"),
    (["--spacing", "0"], "--spacing must be a finite number > 0, got 0.0"),
    (["--radius", "inf"], "--radius must be a finite number > 0, got inf"),
    (["--alt", "nan"], "--alt must be a finite number of metres, got nan"),
])
def test_vehicle_pattern_numbers(argv: list[str], message: str,
                                 capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        parse_args(argv)
    assert exit_.value.code == 2
    assert message in capsys.readouterr().err


def test_vehicle_pattern_numbers_in_range_pass() -> None:
    args = parse_args(["--speed", "3", "--spacing", "10", "--radius", "15", "--alt", "20"])
    assert (args.speed, args.spacing, args.radius, args.alt) == (3.0, 10.0, 15.0, 20.0)


@pytest.mark.parametrize(("argv", "message"), [
    (["--noise", "-5"], "--noise must be a finite std >= 0, got -5.0"),
    (["--mount-pitch", "nan"], "--mount-pitch must be in -180..180 degrees, got nan"),
    (["--mount-pitch", "200"], "--mount-pitch must be in -180..180 degrees, got 200.0"),
    (["--t", "inf"], "--t must be a finite scene time, got inf"),
])
def test_camera_numbers(argv: list[str], message: str, tmp_path: Path,
                        capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        camera_cli.main(["--pose", "0,0,30", "--out", str(tmp_path / "f"), *argv])
    assert exit_.value.code == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "f").exists()


def test_a_southern_home_and_a_western_pose_are_values_not_options(tmp_path: Path) -> None:
    """``uav-sitl vehicle --home -35.362361,149.165230,584`` (beside ArduCopter SITL's default
    home, Canberra) failed with "argument --home: expected one argument": argparse took the
    value for an option. So did a camera pose west or south of the scene's origin."""
    args = parse_args(["--home", "-35.362361,149.165230,584", "--flavour", "ardupilot"])
    assert (args.home.lat_deg, args.home.lon_deg, args.home.alt_m) == (-35.362361, 149.16523,
                                                                      584.0)
    assert parse_args(["--home", "47.3,-122.3"]).home.lon_deg == -122.3
    assert camera_cli.main(["--pose", "-20,-30,30", "--size", "64x48", "--out",
                            str(tmp_path / "f")]) == 0
    assert len(list((tmp_path / "f").iterdir())) == 1
