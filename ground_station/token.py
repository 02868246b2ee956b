"""The control token: generated at first start, stored with 0600 permissions, shown once."""

from __future__ import annotations

import contextlib
import hmac
import os
import secrets
from pathlib import Path

__all__ = ["ensure_token", "read_token", "token_matches"]


def read_token(path: Path) -> str:
    return path.read_text(encoding="utf-8").strip()


def ensure_token(path: Path) -> tuple[str, bool]:
    """Return ``(token, created)``; creates the file (mode 0600, never readable by others)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    token = secrets.token_urlsafe(24)
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except FileExistsError:
        existing = read_token(path)
        if existing:
            mode = path.stat().st_mode & 0o777
            if mode & 0o077:
                with contextlib.suppress(OSError):
                    os.chmod(path, 0o600)
            return existing, False
        path.unlink()
        return ensure_token(path)
    with os.fdopen(fd, "w", encoding="utf-8") as handle:
        handle.write(token + "\n")
        handle.flush()
        os.fsync(handle.fileno())
    return token, True


def token_matches(expected: str, given: str | None) -> bool:
    """Constant-time comparison, so response timing does not leak the token."""
    return given is not None and hmac.compare_digest(expected.encode(), given.encode())
