"""Operator checks (audit 12): Ctrl-C during ``uav-ground-station export`` printed a
KeyboardInterrupt traceback (exit -2). Now one line that says the export is incomplete, and
exit 130, not 0: a script must not take a cut-short export for a finished one."""

from __future__ import annotations

from pathlib import Path

import pytest

import ground_station.export
from ground_station.cli import main


def test_ctrl_c_during_export_is_one_line_and_not_success(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    def interrupted(*_: object, **__: object) -> None:
        raise KeyboardInterrupt  # what Python raises in the copy loop on SIGINT

    monkeypatch.setattr(ground_station.export, "export_mission", interrupted)
    out = tmp_path / "out"
    code = main(["export", "m", "--data-dir", str(tmp_path / "data"), "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 130
    assert err.splitlines() == [f"uav-ground-station: export interrupted; {out} is incomplete"]
