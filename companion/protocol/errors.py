"""Errors of the wire protocol, h11-style: one base, one subclass per kind of bad input.

The decoder raises the ``RemoteProtocolError`` subclasses internally and catches them only in
``Decoder.receive_datagram``, where each is counted under its ``reason`` and the datagram is
dropped. ``LocalProtocolError`` means the caller asked the encoder for something the wire
cannot carry (a sender id longer than 32 bytes, metadata that does not fit a datagram...).
Any other exception escaping the codec is a bug.
"""

from __future__ import annotations

from typing import ClassVar

__all__ = [
    "BadSignature",
    "BadTag",
    "LocalProtocolError",
    "MalformedPacket",
    "OversizePacket",
    "ProtocolError",
    "RemoteProtocolError",
    "ReplayedPacket",
    "StalePacket",
    "UnsupportedVersion",
    "WrongEpoch",
    "WrongFleet",
]


class ProtocolError(Exception):
    """Base of every error the codec raises; not raised itself."""

    reason: ClassVar[str] = "protocol_error"
    """Key under which the decoder counts this error (``Decoder.counters``)."""


class LocalProtocolError(ProtocolError, ValueError):
    """The caller asked to encode something the wire format cannot carry."""

    reason = "local_error"


class RemoteProtocolError(ProtocolError):
    """A received datagram is not acceptable; the decoder counts and drops it."""


class MalformedPacket(RemoteProtocolError):
    """Too short, bad magic, inconsistent lengths, fields out of range, bad metadata JSON."""

    reason = "malformed"


class UnsupportedVersion(RemoteProtocolError):
    """The magic is ours but the protocol version byte is not one this code speaks."""

    reason = "unsupported_version"


class WrongFleet(RemoteProtocolError):
    """The fleet id in the header is not the decoder's fleet."""

    reason = "wrong_fleet"


class BadTag(RemoteProtocolError):
    """The HMAC-SHA256 tag does not match: forged, corrupted, or another fleet key."""

    reason = "bad_tag"


class BadSignature(RemoteProtocolError):
    """A COMMAND without a valid Ed25519 signature of the ground station (or none expected)."""

    reason = "bad_signature"


class WrongEpoch(RemoteProtocolError):
    """A COMMAND for another boot of this companion: captured earlier and replayed."""

    reason = "wrong_epoch"


class StalePacket(RemoteProtocolError):
    """``t_sent`` is further from the receiver's ``now`` than the allowed clock skew."""

    reason = "stale"

    def __init__(self, message: str, *, sender: str | None = None,
                 skew_s: float | None = None) -> None:
        super().__init__(message)
        self.sender = sender
        """The authenticated sender (the tag is checked first)."""
        self.skew_s = skew_s
        """Its ``t_sent`` minus the receiver's ``now``: how far its clock is off."""


class ReplayedPacket(RemoteProtocolError):
    """The packet number was already seen from this sender, or is older than the window."""

    reason = "replayed"


class OversizePacket(RemoteProtocolError):
    """The datagram, the message or its fragment count exceeds a configured limit."""

    reason = "oversize"
