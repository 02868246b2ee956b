"""Datagrams refused for a key or fleet mismatch, told at WARNING with the likely cause.

A drone whose ``command_public_key_file`` is not the station's ``command.pub`` (the station's
``command.key`` or ``fleet.key`` copied instead, or keys of an older ``keygen --force``)
drops every command as ``bad_signature``; the shell saw "no reply" and the companion logged
nothing above DEBUG. Each kind is told at its first datagram, then at most once per
``interval_s`` with how many more there were, so a flood cannot fill the journal.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

__all__ = ["HINTS", "DropWarnings"]

HINTS = {
    "bad_signature": "a command whose Ed25519 signature does not verify with "
                     "ground_station.command_public_key_file: is that file the station's "
                     "command.pub, of its current keys (uav-ground-station keygen)?",
    "bad_tag": "a datagram whose HMAC tag does not match ground_station.fleet_key_file: is "
               "that file the station's fleet.key, of its current keys (or does another "
               "fleet send to this port)?",
    "wrong_fleet": "a datagram of another fleet id: is ground_station.fleet_id the station's?",
    "stale": "a datagram of the fleet stamped too far from this computer's clock: the fleet's "
             "clocks must agree within 30 s; set this computer's clock (chrony or gpsd with "
             "the autopilot's GPS, or NTP), or the station's",
}
"""Refusal reason -> what it usually means; other reasons stay at DEBUG."""


class DropWarnings:
    """Rate-limited WARNINGs for refused datagrams (first one, then one per interval)."""

    def __init__(self, logger: logging.Logger, *, interval_s: float = 60.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._log = logger
        self._interval_s = interval_s
        self._clock = clock
        self._told_at: dict[str, float] = {}
        self._untold: dict[str, int] = {}

    def on_drop(self, reason: str, addr: object, detail: str) -> None:
        hint = HINTS.get(reason)
        if hint is None:
            return
        now = self._clock()
        untold = self._untold.get(reason, 0) + 1
        told_at = self._told_at.get(reason)
        if told_at is not None and now - told_at < self._interval_s:
            self._untold[reason] = untold
            return
        self._told_at[reason] = now
        self._untold[reason] = 0
        if told_at is None:
            self._log.warning("refused %s from %s (%s): %s (the next ones at most once a "
                              "minute)", reason, _where(addr), detail, hint)
        else:
            self._log.warning("refused %d datagram(s) as %s in the last %.0f s, the latest "
                              "from %s (%s): %s", untold, reason, now - told_at, _where(addr),
                              detail, hint)


def _where(addr: object) -> str:
    if isinstance(addr, tuple) and len(addr) >= 2:
        return f"{addr[0]}:{addr[1]}"
    return str(addr)
