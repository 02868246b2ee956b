"""The decoder's replay state on disk, so a restarted station refuses what it accepted before.

The file holds, per sender heard in the last minute, its highest packet number, latest
``t_sent`` and when that was accepted (``Decoder.replay_state``), and whether it was written
at a clean shutdown (``closed``). It is rewritten once a second (atomically: temporary file,
fsync, rename) and at shutdown. After a crash the decoder refuses every datagram a sender
sent before the restart, by that sender's clock (the file may be a second behind what was
accepted; its age does not matter, only that the sender is in it); after a clean shutdown
the saved packet numbers are exact and only those at or below them are refused
(``Decoder.restore_replay_state``). Small: one line of JSON per recent sender.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ground_station.json_state import load_json_state, save_json_state

__all__ = ["SavedReplayState", "load_replay_state", "read_replay_state", "save_replay_state"]


@dataclass(frozen=True, slots=True)
class SavedReplayState:
    senders: dict[str, Any] = field(default_factory=dict)
    closed: bool = False
    """Written when the station stopped receiving (shutdown), not by the periodic save."""


def read_replay_state(path: Path) -> SavedReplayState:
    """The saved state, or an empty one (first start, or a damaged file: logged, never
    fatal)."""
    saved = load_json_state(path, "replay state")
    senders = saved.get("senders")
    if not isinstance(senders, dict):
        return SavedReplayState()
    return SavedReplayState(senders=senders, closed=saved.get("closed") is True)


def load_replay_state(path: Path) -> dict[str, Any]:
    """The saved senders, or {}."""
    return read_replay_state(path).senders


def save_replay_state(path: Path, senders: dict[str, list[float]], *,
                      closed: bool = False) -> None:
    """Replace the file atomically (a crash leaves the old or the new one, never half)."""
    save_json_state(path, {"senders": senders, "closed": closed})
