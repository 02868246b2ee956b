"""Small JSON state files of the station (replay protection, mission state): read tolerantly
once at start, replaced atomically after (temporary file, fsync, rename), so a crash leaves
the old file or the new one, never half of one."""

from __future__ import annotations

import contextlib
import json
import logging
import os
import tempfile
from pathlib import Path
from typing import Any

__all__ = ["load_json_state", "save_json_state"]

log = logging.getLogger(__name__)


def load_json_state(path: Path, what: str) -> dict[str, Any]:
    """The saved object, or {} (first start; an unreadable or damaged file is logged as
    ``what``, never fatal)."""
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        return {}
    except OSError as exc:
        log.warning("%s %s not readable: %s", what, path, exc)
        return {}
    try:
        state = json.loads(raw)
    except (ValueError, RecursionError) as exc:
        log.warning("%s %s is damaged (%s); starting without it", what, path, exc)
        return {}
    return state if isinstance(state, dict) else {}


def save_json_state(path: Path, state: dict[str, Any]) -> None:
    """Replace ``path`` with ``state`` atomically. Blocking (fsync): off the event loop."""
    data = json.dumps(state, separators=(",", ":")).encode()
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
