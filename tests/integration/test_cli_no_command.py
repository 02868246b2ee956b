"""A console script run without a command prints its help and says, on stderr, what to do."""

from __future__ import annotations

from collections.abc import Callable

import pytest

from ground_station.cli import main as ground_station_main
from sitl.cli import main as sitl_main


@pytest.mark.parametrize(("main", "argv", "line"), [
    (ground_station_main, [], "uav-ground-station: choose a command (start with: "
                              "uav-ground-station run)"),
    (sitl_main, [], "uav-sitl: choose a command (the demo fleet: uav-sitl fleet)"),
    (sitl_main, ["study"], "uav-sitl study: choose a study"),
])
def test_no_command_is_help_and_one_error_line(main: Callable[[list[str]], int],
                                               argv: list[str], line: str,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    assert main(argv) == 2
    out, err = capsys.readouterr()
    assert "usage:" in out
    assert err.strip().splitlines() == [line]


@pytest.mark.parametrize(("main", "argv"), [
    (ground_station_main, ["--help"]), (sitl_main, ["--help"]), (sitl_main, ["study", "-h"]),
])
def test_asked_for_help_is_help_and_success(main: Callable[[list[str]], int], argv: list[str],
                                            capsys: pytest.CaptureFixture[str]) -> None:
    try:
        code = main(argv)
    except SystemExit as exit_:  # argparse's own --help
        code = int(exit_.code or 0)
    out, err = capsys.readouterr()
    assert code == 0 and "usage:" in out and err == ""
