"""Ed25519 signatures of mission commands: the ground station's role, which drones lack.

Bulk data (images, telemetry, reports, status) is authenticated with the fleet's shared HMAC
key, which every drone holds. A COMMAND additionally carries an Ed25519 signature made with
the ground station's private key; companions hold only the public key, so a captured drone
can still send data under its own id but cannot make a command any companion obeys
(docs/protocol.md, "Keys and threat model"). Keys travel as raw 32-byte values.
"""

from __future__ import annotations

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey
from cryptography.hazmat.primitives.serialization import Encoding, PublicFormat

from companion.protocol.errors import LocalProtocolError

__all__ = [
    "KEY_BYTES",
    "SIGNATURE_BYTES",
    "CommandSigner",
    "CommandVerifier",
    "decode_key_text",
    "public_key_of",
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


def decode_key_text(text: bytes, what: str) -> bytes:
    """A raw 32-byte key from its file form: one line of base64 (as ``keygen`` writes it)."""
    import base64
    import binascii

    try:
        raw = base64.b64decode(text.strip(), validate=True)
    except (binascii.Error, ValueError) as exc:
        raise LocalProtocolError(f"{what} is not base64 text") from exc
    return _check(raw, what)
