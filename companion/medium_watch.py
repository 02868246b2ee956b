"""Tells at WARNING when a drone's shared medium does not work (docs/peers.md).

Seen on a netns fleet: a drone with ``peers.medium`` on a broadcast address that is not its
network's (``broadcast:10.99.0.255:...`` on a 10.77.0.0/24 radio), or on another port than
the fleet's, ran with nothing above INFO in its log while every peer-bound type (position,
status) it sent was lost: the station showed it without a position or a mode, its peers did
not know it, its ``/peers`` stayed empty. Sans-I/O: the transport calls :meth:`send_failed`
for a send to the medium that failed and :meth:`check` every ``period_s``.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping

from companion.medium import SharedMedium

__all__ = ["CHECK_PERIOD_S", "MediumWatch"]

CHECK_PERIOD_S = 30.0
"""Nothing heard on the medium for this long (while sending on it) is told."""
REPEAT_S = 60.0
"""Failed sends are told at once, then at most once in this long, with their count."""
_HINT = ("every drone's peers.medium and the station's shared_medium must be the same "
         "broadcast address of the fleet network (`ip -4 addr` shows it after brd) or "
         "multicast group, on the same port")


class MediumWatch:
    """State of one drone's medium: ``ok``, ``deaf`` (not even our own datagrams come back)
    or ``alone`` (only ours); a WARNING when it turns bad, an INFO when it is ok again."""

    def __init__(self, medium: SharedMedium, log: logging.Logger, *,
                 period_s: float = CHECK_PERIOD_S, repeat_s: float = REPEAT_S) -> None:
        self.medium = medium
        self.log = log
        self.period_s = period_s
        self.repeat_s = repeat_s
        self.state = "ok"
        self._last: dict[str, int] = {}
        self._failed = 0
        self._failed_told_at: float | None = None
        self._twins: set[tuple[str, int]] = set()

    def own_id_heard(self, addr: tuple[str, int], own_port: int) -> None:
        """A datagram with this drone's sender id from ``addr``: our echo comes from our own
        port; another port is another fleet member with our ``drone.id`` (a copied config).
        Seen: peers then mixed the two (the real drone's position aged 19 s at its peers, its
        status flipped) and the station dropped 246 datagrams as replayed, with no word why."""
        if addr[1] == own_port or addr in self._twins or len(self._twins) >= 8:
            return
        self._twins.add(addr)
        self.log.warning("drone.id: another fleet member at %s:%d sends with this drone's id "
                         "on the shared medium (peers.medium %s): its peers and the ground "
                         "station mix the two and drop their datagrams as replays; give "
                         "every drone its own drone.id", addr[0], addr[1], self.medium)

    def send_failed(self, exc: OSError, now: float) -> None:
        self._failed += 1
        if self._failed_told_at is not None and now - self._failed_told_at < self.repeat_s:
            return
        count = "" if self._failed_told_at is None else f" ({self._failed} times since)"
        self._failed_told_at, self._failed = now, 0
        self.log.warning("peers.medium %s: sending on the shared medium failed (%s)%s: what "
                         "this drone shares with its peers is lost while it fails; the "
                         "network is down, or %s", self.medium, exc.strerror or exc, count,
                         _HINT)

    def check(self, counters: Mapping[str, int]) -> str:
        """Compare the transport's medium counters with the last check's; returns the state."""
        keys = ("medium_sent", "medium_reports_sent", "medium_own_echo", "medium_received")
        delta = {k: counters.get(k, 0) - self._last.get(k, 0) for k in keys}
        self._last = {k: counters.get(k, 0) for k in keys}
        sent = delta["medium_sent"] + delta["medium_reports_sent"]
        if delta["medium_received"] > 0:
            state = "ok"
        elif sent == 0:
            return self.state  # nothing sent, nothing heard: nothing to tell
        else:
            state = "alone" if delta["medium_own_echo"] > 0 else "deaf"
        if state != self.state:
            if state == "deaf":
                self.log.warning(
                    "peers.medium %s: nothing heard on the shared medium for %.0f s, not even "
                    "this drone's own %d messages: the address does not reach this drone's "
                    "fleet network, or the network is down; %s", self.medium, self.period_s,
                    sent, _HINT)
            elif state == "alone":
                self.log.warning(
                    "peers.medium %s: for %.0f s only this drone's own messages were heard "
                    "on the shared medium, no other fleet member's: if other drones fly, %s",
                    self.medium, self.period_s, _HINT)
            else:
                self.log.info("peers.medium %s: other fleet members heard again", self.medium)
        self.state = state
        return state
