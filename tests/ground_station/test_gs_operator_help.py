"""Operator checks (audit 12): ``--help`` says what a user needs. ``uav-ground-station shell
--help`` listed only its options (the commands were behind ``help`` inside the shell), and
``uav-companion run --help`` showed ``--config CONFIG`` with neither default nor template."""

from __future__ import annotations

import pytest

from companion.cli import main as companion_main
from ground_station.cli import main as station_main


def _help(main: object, argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    with pytest.raises(SystemExit) as exit_:
        main(argv)  # type: ignore[operator]
    assert exit_.value.code == 0
    return capsys.readouterr().out


def test_shell_help_lists_the_commands(capsys: pytest.CaptureFixture[str]) -> None:
    text = _help(station_main, ["shell", "--help"], capsys)
    for command in ("start [TIME]", "end [TIME]", "params A=1,B=2", "drones N", "wait",
                    "status", 'drones 3; start +5'):
        assert command in text, command


def test_companion_help_names_the_default_config(capsys: pytest.CaptureFixture[str]) -> None:
    for sub in ("run", "check", "install-service"):
        text = " ".join(_help(companion_main, [sub, "--help"], capsys).split())
        assert "default /etc/uav-companion/config.toml" in text
        assert "examples/companion.toml" in text


def test_station_help_names_its_template(capsys: pytest.CaptureFixture[str]) -> None:
    for sub in ("run", "shell", "export", "token", "keygen"):
        text = " ".join(_help(station_main, [sub, "--help"], capsys).split())
        assert "examples/ground_station.toml is the commented template" in text
