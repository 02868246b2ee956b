"""Ed25519 signatures of mission commands: the ground station's role, which drones lack.

Bulk data (images, telemetry, reports, status) is authenticated with the fleet's shared HMAC
key, which every drone holds. A COMMAND additionally carries an Ed25519 signature made with
the ground station's private key; companions hold only the public key, so a captured drone
can still send data under its own id but cannot make a command any companion obeys
(docs/protocol.md, "Keys and threat model"). Keys travel as raw 32-byte values.

A key file is one line, ``DESCRIPTION: BASE64``, whose description names its kind
(:data:`KEY_FILE_LINES`), so that a reader refuses the station's private ``command.key`` where
the drone's ``command.pub`` belongs: all three were bare base64 lines of 32 bytes, and a drone
given the wrong one dropped every command without a word. A bare base64 line (``keygen``
before the kinds) is still read, untagged. The fleet key is the whole line, as it always
was (an older reader of ``fleet.key`` gets the same HMAC key).
"""

from __future__ import annotations

import base64
import binascii
from typing import Literal

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey
from cryptography.hazmat.primitives.serialization import Encoding, PublicFormat

from companion.protocol.errors import LocalProtocolError

__all__ = [
    "KEY_BYTES",
    "KEY_FILE_LINES",
    "SIGNATURE_BYTES",
    "CommandSigner",
    "CommandVerifier",
    "KeyKind",
    "WrongKeyKind",
    "decode_key_text",
    "fleet_key_text",
    "key_file_line",
    "key_text_kind",
    "public_key_of",
    "same_key",
]

KEY_BYTES = 32
"""Length of an Ed25519 private seed and of a public key."""
SIGNATURE_BYTES = 64


def _check(raw: bytes, what: str) -> bytes:
    if not isinstance(raw, bytes | bytearray) or len(raw) != KEY_BYTES:
        raise LocalProtocolError(f"{what} must be {KEY_BYTES} bytes")
    return bytes(raw)


class CommandSigner:
    """Signs command datagrams; only the ground station has one."""

    __slots__ = ("_key",)

    def __init__(self, private_key: bytes) -> None:
        self._key = Ed25519PrivateKey.from_private_bytes(_check(private_key, "command key"))

    def sign(self, data: bytes) -> bytes:
        return self._key.sign(data)

    @property
    def public_key(self) -> bytes:
        return self._key.public_key().public_bytes(Encoding.Raw, PublicFormat.Raw)


class CommandVerifier:
    """Checks command signatures against the ground station's public key."""

    __slots__ = ("_key",)

    def __init__(self, public_key: bytes) -> None:
        self._key = Ed25519PublicKey.from_public_bytes(_check(public_key, "command public key"))

    def verify(self, data: bytes | memoryview, signature: bytes | memoryview) -> bool:
        try:
            self._key.verify(bytes(signature), bytes(data))
        except InvalidSignature:
            return False
        return True


def public_key_of(private_key: bytes) -> bytes:
    """The raw public key that belongs to a raw private seed."""
    return CommandSigner(private_key).public_key


KeyKind = Literal["fleet key", "command key", "command public key"]

KEY_FILE_LINES: dict[KeyKind, str] = {
    "fleet key": "uav-infodist fleet key (HMAC; the ground station and every drone)",
    "command key": "uav-infodist command key (Ed25519 PRIVATE; the ground station only, "
                   "never a drone)",
    "command public key": "uav-infodist command public key (Ed25519; copy to every drone)",
}
"""What ``keygen`` writes before ``: BASE64`` in each file; the words after
``uav-infodist`` and before `` (`` name the kind."""

_PREFIX = b"uav-infodist "
_FILE_NAMES: dict[KeyKind, str] = {"fleet key": "fleet.key", "command key": "command.key",
                                   "command public key": "command.pub"}
_DESCRIBED: dict[KeyKind, str] = {
    "fleet key": "the fleet key (fleet.key)",
    "command key": "the ground station's PRIVATE command key (command.key)",
    "command public key": "the ground station's command public key (command.pub)",
}


class WrongKeyKind(LocalProtocolError):
    """A key file tagged as another kind of key than the one expected."""

    def __init__(self, what: str, found: KeyKind, expected: KeyKind) -> None:
        self.found = found
        self.expected = expected
        if found == "command key" and expected == "command public key":
            fix = "copy command.pub to the drone, and never command.key"
        elif found == "command key":
            fix = f"use {_FILE_NAMES[expected]} (command.key stays on the ground station)"
        else:
            fix = f"use {_FILE_NAMES[expected]}"
        super().__init__(f"{what} is {_DESCRIBED[found]}, not {_DESCRIBED[expected]}: {fix}")


def key_file_line(kind: KeyKind, key: bytes) -> bytes:
    """A key file's line (without its newline) for a raw 32-byte ``key``."""
    return KEY_FILE_LINES[kind].encode() + b": " + base64.b64encode(key)


def _split(text: bytes, what: str) -> tuple[KeyKind | None, bytes]:
    line = bytes(text).strip()
    if not line.startswith(_PREFIX):
        return None, line
    head, sep, key = line.rpartition(b": ")
    name = head[len(_PREFIX):].partition(b" (")[0].decode("utf-8", "replace")
    kind = next((k for k in KEY_FILE_LINES if k == name), None)
    if sep and kind is not None:
        return kind, key.strip()
    raise LocalProtocolError(f"{what} is not a key file: its line starts like one ("
                             f"{_PREFIX.decode()}...) but names no known kind of key")


def key_text_kind(text: bytes, what: str) -> KeyKind | None:
    """The kind a key file's line names, or None for a bare (untagged, older) file."""
    return _split(text, what)[0]


def decode_key_text(text: bytes, what: str, *, kind: KeyKind | None = None) -> bytes:
    """A raw 32-byte key from its file form, ``DESCRIPTION: BASE64`` or a bare base64 line.
    With ``kind``, a file tagged as another kind raises :class:`WrongKeyKind`."""
    found, key = _split(text, what)
    if kind is not None and found is not None and found != kind:
        raise WrongKeyKind(what, found, kind)
    try:
        raw = base64.b64decode(key, validate=True)
    except (binascii.Error, ValueError) as exc:
        raise LocalProtocolError(f"{what} is not base64 text") from exc
    return _check(raw, what)


def fleet_key_text(text: bytes, what: str) -> bytes:
    """The fleet's HMAC key from ``fleet.key``: the base64 text after its kind (a bare,
    older file is all key), so the description line can be reworded without changing it."""
    return _split(text, what)[1]


def same_key(fleet_key: bytes, raw: bytes) -> bool:
    """Whether the raw 32-byte ``raw`` is the fleet key ``fleet_key`` (its text as read from
    ``fleet.key``, tagged or not): a command key file that is really the fleet key."""
    line = bytes(fleet_key).strip()
    key = line.rpartition(b": ")[2] if line.startswith(_PREFIX) else line
    try:
        decoded = base64.b64decode(key, validate=True)
    except (binascii.Error, ValueError):
        decoded = b""
    return bytes(raw) in (decoded, key, line)
