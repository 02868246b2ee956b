"""Reading secret key files the way ssh does: refuse one that others may read.

A fleet key (HMAC) or a command key (Ed25519 seed) readable by group or others is a key
another local user may already have copied; starting with it would hide that. The check is
on the file as opened (no race between the check and the read).
"""

from __future__ import annotations

import contextlib
import os
import stat
from pathlib import Path

from companion.protocol.errors import LocalProtocolError
from companion.protocol.signing import KeyKind, WrongKeyKind, fleet_key_text, key_text_kind

__all__ = ["UnsafeKeyFile", "make_private_dir", "read_key_file", "read_secret"]


class UnsafeKeyFile(OSError):
    """The key file is readable or writable by group/others (or not a regular file)."""


def read_secret(path: Path) -> bytes:
    """The bytes of a secret key file; raises :class:`UnsafeKeyFile` when its mode lets
    anyone but the owner read or change it, OSError when it cannot be read."""
    fd = os.open(path, os.O_RDONLY)
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise UnsafeKeyFile(f"{path} is not a regular file")
        mode = stat.S_IMODE(info.st_mode)
        if mode & 0o077:
            raise UnsafeKeyFile(
                f"{path} has mode {mode:04o}: others may read it (chmod 600 {path})")
        with os.fdopen(os.dup(fd), "rb") as handle:
            return handle.read()
    finally:
        os.close(fd)


def read_key_file(path: Path, kind: KeyKind, what: str) -> bytes:
    """The text of a key file that should hold a ``kind`` key: :class:`WrongKeyKind` when
    ``keygen`` tagged it as another kind (told before its mode: ``command.pub`` named as the
    fleet key is 0644, and "others may read it" hid the real mistake), then as
    :func:`read_secret` for the secret kinds; a public key is read whatever its mode."""
    if kind == "command public key":
        text = path.read_bytes()
    else:
        try:
            text = read_secret(path)
        except UnsafeKeyFile:
            with contextlib.suppress(OSError):
                _check_kind(path.read_bytes(), kind, what)
            raise
    _check_kind(text, kind, what)
    return fleet_key_text(text, what) if kind == "fleet key" else text


def _check_kind(text: bytes, kind: KeyKind, what: str) -> None:
    try:
        found = key_text_kind(text, what)
    except LocalProtocolError:
        return  # the key's own reader says what is wrong with it
    if found is not None and found != kind:
        raise WrongKeyKind(what, found, kind)


def make_private_dir(path: Path) -> None:
    """Create ``path`` and its missing parents readable by their owner alone (0700). A
    station's data folder holds every image and position of the fleet: made with the
    default umask it was readable by every local user (docs/security.md, 2026-11-24). A
    folder that exists keeps its mode (the operator chose it)."""
    missing: list[Path] = []
    while not path.exists() and path != path.parent:
        missing.append(path)
        path = path.parent
    for folder in reversed(missing):
        with contextlib.suppress(FileExistsError):  # made meanwhile by another process
            folder.mkdir(mode=0o700)
