"""Image files on disk, crash-safe: written to a temp name, fsync'd, renamed into place.

A crash never leaves half an image under its final name; what it can leave (a
``.NAME.jpg.tmp``) is removed when a writer opens. Split from :mod:`ground_station.storage`
(issue 14); ``Storage`` runs these on its file-writer threads.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

__all__ = ["fsync_dir", "remove_temp_files", "write_atomically"]


def fsync_dir(directory: Path) -> None:
    """Make a rename in ``directory`` durable (best effort: not every filesystem can)."""
    with contextlib.suppress(OSError):
        fd = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def remove_temp_files(root: Path) -> int:
    """Half-written images of a process that died mid-write (``.NAME.jpg.tmp``): never
    indexed, never under a final name, only taking space. Returns how many went."""
    removed = 0
    for tmp in (root / "missions").glob("*/images/*/.*.tmp"):
        with contextlib.suppress(OSError):
            tmp.unlink()
            removed += 1
    return removed


def write_atomically(final: Path, payload: bytes, *, fsync: bool, made_dirs: set[Path]) -> None:
    """Write ``payload`` to ``final`` via a temp file; raises OSError (full disk) leaving
    nothing behind. ``made_dirs``: folders known to exist (no mkdir syscall per image)."""
    folder = final.parent
    if folder not in made_dirs:
        folder.mkdir(parents=True, exist_ok=True)
        made_dirs.add(folder)
    tmp = final.with_name(f".{final.name}.tmp")
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    except FileNotFoundError:  # the folder was removed while running: make it again
        made_dirs.discard(folder)
        folder.mkdir(parents=True, exist_ok=True)
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    try:
        view = memoryview(payload)
        while view:
            written = os.write(fd, view)
            view = view[written:]
        if fsync:
            os.fsync(fd)
    except BaseException:
        os.close(fd)
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    os.close(fd)
    os.replace(tmp, final)
