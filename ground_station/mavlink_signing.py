"""MAVLink 2 signing for the fleet mirror, with a verifier of our own (sans-I/O).

With ``mavlink_signing_key_file`` set, every frame the mirror sends is signed (each drone's
encoder signs with the shared key, link id 0) and a client's frame counts only if its
signature verifies, its timestamp is newer than the last one of its stream (link id,
system, component), and a new stream's is at most a minute old: a stranger's HEARTBEAT is
ignored, and a captured one replayed from another address too.

Why not pymavlink's own check (2.4.50): it records a stream's timestamp *before* comparing
the signature, so one forged frame with a far-future timestamp would make every later
genuine frame of that stream "old" and lock the real GCS out. Here the timestamp is kept
only once the signature is good, and for at most ``MAX_STREAMS`` streams.
"""

from __future__ import annotations

import hashlib
import hmac
from collections import OrderedDict
from typing import Any

__all__ = ["MAX_STREAMS", "SignedFrames", "signing_timestamp"]

EPOCH_2015 = 1_420_070_400
"""MAVLink signing timestamps count 10 us units from 2015-01-01 UTC."""
NEW_STREAM_MAX_AGE = 6_000_000
"""A stream not seen before may start at most 60 s in the past (the MAVLink rule)."""
MAX_STREAMS = 64
SIGNATURE_BLOCK = 13  # link id (1), timestamp (6), signature (6)
IFLAG_SIGNED = 0x01


def signing_timestamp(now: float) -> int:
    return max(0, int((now - EPOCH_2015) * 100_000))


class SignedFrames:
    """Signs the mirror's encoders and checks what clients send (module docstring)."""

    def __init__(self, key: bytes) -> None:
        if len(key) != 32:
            raise ValueError("a MAVLink signing key is 32 bytes")
        self.key = key
        self.streams: OrderedDict[tuple[int, int, int], int] = OrderedDict()

    def sign_with(self, encoder: Any) -> None:
        """Make ``encoder`` (a pymavlink ``MAVLink``) sign every frame it packs."""
        encoder.signing.secret_key = self.key
        encoder.signing.sign_outgoing = True
        encoder.signing.link_id = 0

    @staticmethod
    def advance(encoder: Any, now: float) -> None:
        """Before a frame: the timestamp follows the clock (pymavlink only adds 1 a frame,
        and a GCS that starts later refuses a stream a minute behind its own clock)."""
        encoder.signing.timestamp = max(encoder.signing.timestamp, signing_timestamp(now))

    def check(self, msg: Any, now: float) -> str | None:
        """None for a frame signed with the key and fresh; otherwise the counter to raise."""
        frame = bytes(msg.get_msgbuf())
        if len(frame) < 12 + SIGNATURE_BLOCK or frame[0] != 0xFD or not frame[2] & IFLAG_SIGNED:
            return "unsigned"
        expected = hashlib.sha256(self.key + frame[:-6]).digest()[:6]
        if not hmac.compare_digest(expected, frame[-6:]):
            return "bad_signature"
        stream = (frame[-SIGNATURE_BLOCK], msg.get_srcSystem(), msg.get_srcComponent())
        stamp = int.from_bytes(frame[-12:-6], "little")
        last = self.streams.get(stream)
        if last is not None and stamp <= last:
            return "replayed_signature"
        if last is None and stamp + NEW_STREAM_MAX_AGE < signing_timestamp(now):
            return "stale_signature"
        self.streams[stream] = stamp
        self.streams.move_to_end(stream)
        while len(self.streams) > MAX_STREAMS:
            self.streams.popitem(last=False)
        return None
