"""The decoder's replay state on disk, so a restarted station refuses what it accepted before.

The file holds, per sender heard in the last minute, its highest packet number, latest
``t_sent`` and when that was accepted (``Decoder.replay_state``). It is rewritten once a
second (atomically: temporary file, fsync, rename) and at shutdown. After a restart the
decoder refuses every datagram a sender sent before the restart, by that sender's clock
(``Decoder.restore_replay_state``) -- the file's age does not matter, only that the sender is
in it. Small: one line of JSON per recent sender.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ground_station.json_state import load_json_state, save_json_state

__all__ = ["load_replay_state", "save_replay_state"]


def load_replay_state(path: Path) -> dict[str, Any]:
    """The saved state, or {} (first start, or a damaged file: logged, never fatal)."""
    senders = load_json_state(path, "replay state").get("senders")
    return senders if isinstance(senders, dict) else {}


def save_replay_state(path: Path, senders: dict[str, list[float]]) -> None:
    """Replace the file atomically (a crash leaves the old or the new one, never half)."""
    save_json_state(path, {"senders": senders})
