"""The decoder's replay state on disk, so a restarted station refuses what it accepted before.

The file holds, per sender heard in the last minute, its highest packet number, latest
``t_sent`` and when that was accepted (``Decoder.replay_state``). It is rewritten once a
second (atomically: temporary file, fsync, rename) and at shutdown. After a restart the
decoder refuses every datagram a sender sent before the restart, by that sender's clock
(``Decoder.restore_replay_state``) -- the file's age does not matter, only that the sender is
in it. Small: one line of JSON per recent sender.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import tempfile
from pathlib import Path
from typing import Any

__all__ = ["load_replay_state", "save_replay_state"]

log = logging.getLogger(__name__)


def load_replay_state(path: Path) -> dict[str, Any]:
    """The saved state, or {} (first start, or a damaged file: logged, never fatal)."""
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        return {}
    except OSError as exc:
        log.warning("replay state %s not readable: %s", path, exc)
        return {}
    try:
        state = json.loads(raw)
    except (ValueError, RecursionError) as exc:
        log.warning("replay state %s is damaged (%s); starting without it", path, exc)
        return {}
    senders = state.get("senders") if isinstance(state, dict) else None
    return senders if isinstance(senders, dict) else {}


def save_replay_state(path: Path, senders: dict[str, list[float]]) -> None:
    """Replace the file atomically (a crash leaves the old or the new one, never half)."""
    data = json.dumps({"senders": senders}, separators=(",", ":")).encode()
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name + ".", suffix=".tmp")
    try:
        try:
            os.write(fd, data)
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
