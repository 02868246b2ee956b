"""The replay-state file: atomic replacement, private mode, damage tolerated at start."""

from __future__ import annotations

import logging
import stat
from pathlib import Path

import pytest

from ground_station.replay_state import load_replay_state, read_replay_state, save_replay_state


def test_round_trip_and_mode(tmp_path: Path) -> None:
    path = tmp_path / "replay_state.json"
    assert load_replay_state(path) == {}  # first start
    state = {"uav1": [7 << 32, 1_700_000_001.5, 1_700_000_000.0]}
    save_replay_state(path, state)
    assert load_replay_state(path) == state
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    save_replay_state(path, {})
    assert load_replay_state(path) == {}
    assert [p.name for p in tmp_path.iterdir()] == ["replay_state.json"]  # no temp left
    assert read_replay_state(path).closed is False  # the periodic save
    save_replay_state(path, state, closed=True)  # the last one, at shutdown
    assert read_replay_state(path).closed is True
    assert read_replay_state(path).senders == state


@pytest.mark.parametrize("text", [b"", b"{", b"[1, 2]", b'{"senders": 3}', b"\xff\xfe"])
def test_a_damaged_file_is_reported_not_fatal(tmp_path: Path, text: bytes,
                                              caplog: pytest.LogCaptureFixture) -> None:
    path = tmp_path / "replay_state.json"
    path.write_bytes(text)
    with caplog.at_level(logging.WARNING):
        assert load_replay_state(path) == {}


def test_an_unwritable_folder_raises_oserror(tmp_path: Path) -> None:
    with pytest.raises(OSError):
        save_replay_state(tmp_path / "missing" / "replay_state.json", {})
