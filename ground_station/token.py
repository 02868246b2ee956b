"""The control token: generated at first start, stored with 0600 permissions, shown once."""

from __future__ import annotations

import contextlib
import hmac
import os
import secrets
from pathlib import Path

from companion.secret_files import make_private_dir

__all__ = [
    "PAGE_KEY_HEADER",
    "SESSION_COOKIE",
    "LoginCodes",
    "ensure_token",
    "login_code",
    "page_key",
    "read_token",
    "session_value",
    "token_matches",
]


def read_token(path: Path) -> str:
    return path.read_text(encoding="utf-8").strip()


def ensure_token(path: Path) -> tuple[str, bool]:
    """Return ``(token, created)``; creates the file (mode 0600, never readable by others)."""
    make_private_dir(path.parent)
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


# -- browser sessions -----------------------------------------------------------------------
# The dashboard never keeps the control token in JavaScript or in a URL: a browser holds an
# HttpOnly session cookie derived from it, obtained either with a one-time login code in
# the dashboard URL (printed at start, or by ``uav-ground-station token --url``) or by
# POSTing the token in a header (the token box). Rotating the token file ends all sessions.

SESSION_COOKIE = "gs_session"
PAGE_KEY_HEADER = "X-GS-Key"
LOGIN_TTL_S = 600.0


def session_value(token: str) -> str:
    """The session cookie's value: a MAC of the token, so the cookie never is the token."""
    return hmac.new(token.encode(), b"uav-infodist dashboard session", "sha256").hexdigest()


def page_key(token: str) -> str:
    """The second half of a browser session, which only the station's own page holds.

    Cookies are not isolated by port: the browser sends the session cookie to every server
    on the station's host name (``http://127.0.0.1:OTHER``: another user's program on a
    shared computer, any local service that logs its requests), which could replay it with
    a forged ``Origin``. Storage is isolated by origin, port included: the page keeps this
    key in ``localStorage`` and sends it with the cookie (``X-GS-Key`` or ``?key=``); it is
    handed out only at login (the login link's redirect fragment, the token box's answer),
    so the cookie alone opens nothing."""
    return hmac.new(token.encode(), b"uav-infodist dashboard page key", "sha256").hexdigest()[:32]


def _login_mac(token: str, message: str) -> str:
    return hmac.new(token.encode(), b"login:" + message.encode(), "sha256").hexdigest()[:32]


def login_code(token: str, *, now: float, ttl_s: float = LOGIN_TTL_S) -> str:
    """A one-time code for ``/?login=CODE``: valid ``ttl_s`` seconds, once."""
    message = f"{int(now + ttl_s)}.{secrets.token_urlsafe(12)}"
    return f"{message}.{_login_mac(token, message)}"


class LoginCodes:
    """Redeems login codes: a code is accepted once, before it expires."""

    def __init__(self, token: str) -> None:
        self._token = token
        self._used: dict[str, float] = {}

    def redeem(self, code: str, *, now: float) -> bool:
        expires_text, _, rest = code.partition(".")
        nonce, _, mac = rest.partition(".")
        if not (expires_text.isdigit() and nonce and mac) or len(code) > 200:
            return False
        message = f"{expires_text}.{nonce}"
        if not hmac.compare_digest(_login_mac(self._token, message), mac):
            return False
        expires = float(expires_text)
        if expires < now or expires > now + 2 * LOGIN_TTL_S or message in self._used:
            return False
        for old in [m for m, t in self._used.items() if t < now]:
            del self._used[old]
        self._used[message] = expires
        return True
