"""The ground station's address from its host name: looked up once at start, and retried in
the background while it does not resolve.

A drone that boots before its DNS (a VPN or a radio link that comes up later) or with a typo
in ``ground_station.host`` died with a 40-line ExceptionGroup ending in ``gaierror(-2, 'Name
or service not known')``, naming neither the setting nor the name. Now the first failure is a
WARNING naming both; the companion keeps running (MAVLink, camera, mission log) and sends to
the station once the name resolves. ``uav-companion check`` fails on such a name.
"""

from __future__ import annotations

import asyncio
import itertools
import logging
import socket
from collections.abc import Callable

__all__ = ["RESOLVE_RETRY_S", "RESOLVE_TIMEOUT_S", "RemoteLookup", "lookup_problem"]

log = logging.getLogger("companion.transport")

RESOLVE_RETRY_S = 5.0
"""How often a host name that did not resolve is looked up again."""
RESOLVE_TIMEOUT_S = 5.0
"""How long one lookup may take (with a dead DNS server glibc waits 10 s and more)."""


async def _resolve(addr: tuple[str, int]) -> tuple[str, int]:
    loop = asyncio.get_running_loop()
    async with asyncio.timeout(RESOLVE_TIMEOUT_S):
        infos = await loop.getaddrinfo(addr[0], addr[1], family=socket.AF_INET,
                                       type=socket.SOCK_DGRAM)
    host, port = infos[0][4][:2]
    return (str(host), int(port))


def _why(exc: BaseException) -> str:
    if isinstance(exc, TimeoutError):
        return f"no answer within {RESOLVE_TIMEOUT_S:g} s"
    return str(exc.strerror) if isinstance(exc, OSError) and exc.strerror else str(exc)


def lookup_problem(host: str, port: int, what: str) -> str | None:
    """Why ``host`` does not resolve, in one line naming ``what`` (for ``check``), or None."""
    try:
        socket.getaddrinfo(host, port, family=socket.AF_INET, type=socket.SOCK_DGRAM)
    except (OSError, UnicodeError) as exc:
        return f"{what} {host!r} does not resolve ({_why(exc)})"
    return None


class RemoteLookup:
    """Resolves ``addr`` at :meth:`first`; on failure warns and retries in a task that calls
    ``on_resolved`` with the address once it resolves."""

    def __init__(self, addr: tuple[str, int], what: str,
                 on_resolved: Callable[[tuple[str, int]], None]) -> None:
        self.addr = addr
        self.what = what
        self._on_resolved = on_resolved
        self._task: asyncio.Task[None] | None = None

    async def first(self) -> tuple[str, int] | None:
        """The address, or None after a WARNING (the retries have started)."""
        try:
            return await _resolve(self.addr)
        except (OSError, UnicodeError, TimeoutError) as exc:
            log.warning("%s %r does not resolve (%s): nothing is sent to it until it does; "
                        "retrying every %g s", self.what, self.addr[0], _why(exc),
                        RESOLVE_RETRY_S)
        self._task = asyncio.get_running_loop().create_task(self._retry())
        return None

    async def _retry(self) -> None:
        for attempt in itertools.count(2):
            await asyncio.sleep(RESOLVE_RETRY_S)
            try:
                addr = await _resolve(self.addr)
            except (OSError, UnicodeError, TimeoutError) as exc:
                if attempt % round(60.0 / RESOLVE_RETRY_S) == 0:  # about once a minute
                    log.warning("%s %r still does not resolve after %d tries (%s)",
                                self.what, self.addr[0], attempt, _why(exc))
                continue
            log.info("%s %r resolved to %s:%d", self.what, self.addr[0], *addr)
            self._task = None
            self._on_resolved(addr)
            return

    def cancel(self) -> None:
        if self._task is not None:
            self._task.cancel()
            self._task = None
