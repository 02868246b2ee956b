"""A simulated flight controller's MAVLink links (its TELEM ports), each with its own streams.

A real autopilot keeps message intervals per link: ArduPilot per channel (its SRn_ groups and
SET_MESSAGE_INTERVAL act on the channel they arrived on), PX4 per MAVLink instance. A
companion on TELEM2 and a GCS on TELEM1 (or USB, or UDP) therefore never change each other's
rates; two clients on *one* link (two UDP peers of one port, a GCS behind the companion's
router) do: a GCS's REQUEST_DATA_STREAM then overrides the companion's per-message rates, as
ArduPilot's ``initialise_message_intervals_for_stream`` does.

Replies (COMMAND_ACK, PARAM_VALUE of a read, the mission protocol, TIMESYNC) go to the link
the request came in on; STATUSTEXT, the HEARTBEAT of a mode change, mission progress and home
go to every link, as ``gcs().send_text`` and ``send_to_active_channels`` do. A client's
HEARTBEAT is routed to the other links and to the other clients of its own link.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Hashable, Mapping
from dataclasses import dataclass, field

__all__ = ["DEFAULT_LINK", "LinkStreams"]

DEFAULT_LINK: Hashable = 0
"""The link of a vehicle served on one socket or one serial line."""


@dataclass(slots=True)
class LinkStreams:
    """One link's message intervals (wall seconds), due times and frames to send."""

    intervals: dict[int, float]
    next_due: dict[int, float]
    out: list[bytes] = field(default_factory=list)
    forwards: deque[tuple[object, bytes]] = field(default_factory=lambda: deque(maxlen=64))
    """(sender, frame) of clients' HEARTBEATs: the sender's address when it came on this link
    (the shell sends it to the link's other clients only), None when on another link."""

    @classmethod
    def fresh(cls, defaults: Mapping[int, float], now: float) -> LinkStreams:
        """A link at boot: the flavour's default streams, all due now."""
        return cls(intervals=dict(defaults), next_due=dict.fromkeys(defaults, now))

    def next_deadline(self) -> float | None:
        return min(self.next_due.values()) if self.next_due else None
