"""Byte layout of every datagram: constants, struct formats, the HMAC tag (docs/protocol.md).

Every integer and float is big-endian (network byte order, struct ``!``). A datagram is::

    common header (27 bytes) | sender id (n bytes) | body (body_len bytes) | tag (16 bytes)

and the tag is HMAC-SHA256(fleet key, every byte before the tag) truncated to 16 bytes.
A COMMAND body ends with an Ed25519 signature (64 bytes) of the ground station over every
byte before it (companion.protocol.signing).
"""

from __future__ import annotations

import enum
import hmac
import json
import math
import struct
from collections.abc import Callable, Mapping
from typing import Any, NamedTuple, NoReturn, Protocol

from companion.protocol.errors import (
    BadTag,
    LocalProtocolError,
    MalformedPacket,
    OversizePacket,
    UnsupportedVersion,
    WrongFleet,
)

__all__ = [
    "COMMAND_FIXED",
    "DATA_FIXED",
    "HEADER",
    "MAGIC",
    "MAX_DATAGRAM_BYTES",
    "MAX_ID_BYTES",
    "MAX_JSON_INT",
    "MIN_KEY_BYTES",
    "PROTOCOL_VERSION",
    "REPORT_FIXED",
    "SIGNATURE_BYTES",
    "STATUS_FIXED",
    "TAG_BYTES",
    "Header",
    "KeyedMac",
    "PacketKind",
    "check_key",
    "dumps_json",
    "encode_id",
    "keyed_mac",
    "loads_json_object",
    "pack_datagram",
    "unpack_datagram",
    "unpack_header",
]

MAGIC = b"UV"
"""First two bytes of every datagram (0x55 0x56)."""
PROTOCOL_VERSION = 2
"""2: commands carry the target's boot epoch and the ground station's Ed25519 signature."""
MAX_DATAGRAM_BYTES = 1200
"""UDP payload bound that keeps datagrams below any sane path MTU (ARCHITECTURE.md)."""
TAG_BYTES = 16
"""HMAC-SHA256 truncated to 128 bits (as RFC 4868 does for IPsec)."""
MAX_ID_BYTES = 32
"""Longest sender id, message type, command name, state... in UTF-8 bytes."""
MIN_KEY_BYTES = 16
SIGNATURE_BYTES = 64
"""Ed25519 signature closing a COMMAND body."""

HEADER = struct.Struct("!2sBBIQdHB")
"""magic, version, kind, fleet id, packet number, t_sent, body length, sender id length."""
DATA_FIXED = struct.Struct("!IdHHIB")
"""seq, t_gen, fragment index, fragment count, total payload length, type length."""
METADATA_LEN = struct.Struct("!H")
REPORT_FIXED = struct.Struct("!IHH")
"""report number, part index, part count."""
COMMAND_FIXED = struct.Struct("!QIdB")
"""target's boot epoch, command id, t_exec, name length."""
STATUS_FIXED = struct.Struct("!IB")
"""command id (0: unsolicited), state length."""
U8 = struct.Struct("!B")

OVERHEAD_BYTES = HEADER.size + TAG_BYTES
"""Bytes of every datagram outside the sender id and the body."""


class PacketKind(enum.IntEnum):
    """Byte 3 of the header."""

    DATA = 1
    """A fragment of a message, drone -> ground."""
    REPORT = 2
    """Receiver report, ground -> drones."""
    COMMAND = 3
    """Mission manager command, ground -> drones."""
    STATUS = 4
    """Command acknowledgement or status, drone -> ground."""


class Header(NamedTuple):
    """The authenticated common header of a datagram (a tuple: built per datagram, and a
    frozen dataclass costs several microseconds more to construct)."""

    kind: PacketKind
    fleet_id: int
    packet_number: int
    """Per sender, strictly increasing; the replay window runs over it."""
    t_sent: float
    """Sender's clock when the datagram was encoded, seconds."""
    sender: str


def check_key(key: bytes) -> bytes:
    if not isinstance(key, bytes | bytearray) or len(key) < MIN_KEY_BYTES:
        raise LocalProtocolError(f"fleet key must be at least {MIN_KEY_BYTES} bytes")
    return bytes(key)


def encode_id(value: str, what: str, *, allow_empty: bool = False) -> bytes:
    """UTF-8 bytes of a short identifier, checked against ``MAX_ID_BYTES``."""
    raw = value.encode("utf-8")
    if not raw and not allow_empty:
        raise LocalProtocolError(f"{what} must not be empty")
    if len(raw) > MAX_ID_BYTES:
        raise LocalProtocolError(f"{what} {value!r} is {len(raw)} bytes; at most {MAX_ID_BYTES}")
    return raw


def decode_id(raw: bytes, what: str) -> str:
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise MalformedPacket(f"{what} is not UTF-8") from exc


def dumps_json(value: Any, what: str) -> bytes:
    """Compact, strict JSON (no NaN/Infinity) as UTF-8 bytes."""
    try:
        text = json.dumps(value, separators=(",", ":"), ensure_ascii=False, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise LocalProtocolError(f"{what} is not JSON-encodable: {exc}") from exc
    return text.encode("utf-8")


def _reject_constant(name: str) -> Any:
    raise MalformedPacket(f"non-standard JSON constant {name}")


MAX_JSON_INT = 2**63 - 1
"""Largest |integer| any JSON value may hold (what SQLite and every consumer can store)."""


def _parse_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):  # 1e999 parses to inf
        raise MalformedPacket(f"JSON number {text[:24]} is out of range")
    return value


def _parse_int(text: str) -> int:
    # a length check first: int() of thousands of digits costs quadratic time
    if len(text) > 20 or not -MAX_JSON_INT - 1 <= (value := int(text)) <= MAX_JSON_INT:
        raise MalformedPacket(f"JSON integer {text[:24]} is out of range")
    return value


_DECODER = json.JSONDecoder(
    parse_constant=_reject_constant, parse_float=_parse_float, parse_int=_parse_int
)
"""Built once: json.loads with an option builds a new decoder per call (a third slower).
Rejects NaN/Infinity, numbers that overflow to infinity and integers beyond 64 bits, so
nothing downstream ever sees a non-finite float or an integer SQLite cannot hold."""


def loads_json(raw: bytes, what: str) -> Any:
    try:
        return _DECODER.decode(raw.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise MalformedPacket(f"{what} is not valid JSON: {exc}") from exc


def loads_json_object(raw: bytes, what: str) -> Mapping[str, Any]:
    value = loads_json(raw, what)
    if not isinstance(value, dict):
        raise MalformedPacket(f"{what} must be a JSON object")
    return value


class KeyedMac(Protocol):
    """The part of an HMAC object the codec uses (``hmac.HMAC`` or OpenSSL's own)."""

    def copy(self) -> KeyedMac: ...

    def update(self, data: bytes | memoryview, /) -> None: ...

    def digest(self) -> bytes: ...


def tag(key: bytes, signed: bytes | memoryview) -> bytes:
    mac = keyed_mac(key).copy()
    mac.update(signed)
    return mac.digest()[:TAG_BYTES]


_KEYED_MACS: dict[bytes, KeyedMac] = {}
_MAX_KEYED_MACS = 16


def _new_keyed_mac(key: bytes) -> KeyedMac:
    """OpenSSL's HMAC object itself when there is one: ``hmac.HMAC.copy`` wraps it in Python
    (about 0.8 us of the ~4 us a 1200-byte tag costs)."""
    try:
        import _hashlib

        mac: KeyedMac = _hashlib.hmac_new(key, b"", "sha256")
    except (ImportError, AttributeError, ValueError):  # pragma: no cover - no OpenSSL
        mac = hmac.new(key, digestmod="sha256")
    return mac


def keyed_mac(key: bytes) -> KeyedMac:
    """An HMAC-SHA256 already keyed with ``key``: copying it skips hashing the key pads
    again for every datagram (about a fifth of the tag's cost at 1200 bytes; the one-shot
    ``hmac.digest`` re-keys per call and is slower here)."""
    mac = _KEYED_MACS.get(key)
    if mac is None:
        if len(_KEYED_MACS) >= _MAX_KEYED_MACS:  # a few keys per process; stay bounded
            _KEYED_MACS.clear()
        mac = _KEYED_MACS[key] = _new_keyed_mac(key)
    return mac


_KINDS = {kind.value: kind for kind in PacketKind}


def pack_datagram(
    *,
    key: bytes,
    kind: PacketKind,
    fleet_id: int,
    packet_number: int,
    t_sent: float,
    sender_raw: bytes,
    body: bytes,
    sign: Callable[[bytes], bytes] | None = None,
) -> bytes:
    """Header + sender + body (+ signature) + tag; the caller has already bounded the body.

    With ``sign`` (commands), the body ends with ``sign(every byte before the signature)``.
    """
    body_len = len(body) + (SIGNATURE_BYTES if sign is not None else 0)
    signed = (
        HEADER.pack(
            MAGIC,
            PROTOCOL_VERSION,
            kind,
            fleet_id,
            packet_number,
            t_sent,
            body_len,
            len(sender_raw),
        )
        + sender_raw
        + body
    )
    if sign is not None:
        signed += sign(signed)
    return signed + tag(key, signed)


def unpack_datagram(
    data: bytes, *, key: bytes, fleet_id: int, max_datagram_bytes: int
) -> tuple[Header, memoryview]:
    """Check structure, fleet and tag; return the header and the (authenticated) body.

    Cheap structural checks come first, so garbage costs no HMAC; nothing of the body is
    trusted before the tag is verified.
    """
    data = bytes(data)  # a no-op for bytes; a bytearray's slices could not be hashed
    header, body_start = unpack_header(
        data, mac=keyed_mac(key), fleet_id=fleet_id, max_datagram_bytes=max_datagram_bytes,
        names={},
    )
    return header, memoryview(data)[body_start : len(data) - TAG_BYTES]


_HEADER_UNPACK = HEADER.unpack_from
_HEADER_SIZE = HEADER.size
_COMPARE = hmac.compare_digest
_MAX_NAMES = 1024


def unpack_header(
    data: bytes, *, mac: KeyedMac, fleet_id: int, max_datagram_bytes: int,
    names: dict[bytes, str],
) -> tuple[Header, int]:
    """:func:`unpack_datagram` for a decoder's hot path: the header and where the body
    starts (it ends ``TAG_BYTES`` before the datagram does). ``mac`` is the fleet key's
    :func:`keyed_mac`; ``names`` caches sender ids already decoded (authenticated ones only,
    bounded), so a sender's id is checked as UTF-8 once, not per datagram."""
    n = len(data)
    if n > max_datagram_bytes:
        raise OversizePacket(f"datagram of {n} bytes > {max_datagram_bytes}")
    if n < OVERHEAD_BYTES + 1:
        raise MalformedPacket(f"datagram of {n} bytes is shorter than a header")
    magic, version, kind, fleet, pn, t_sent, body_len, sender_len = _HEADER_UNPACK(data, 0)
    if (
        magic != MAGIC
        or version != PROTOCOL_VERSION
        or fleet != fleet_id
        or not 1 <= sender_len <= MAX_ID_BYTES
        or n != OVERHEAD_BYTES + sender_len + body_len
    ):
        _structure_error(magic, version, fleet, fleet_id, sender_len, body_len, n)
    end = n - TAG_BYTES
    view = memoryview(data)
    check = mac.copy()
    check.update(view[:end])
    if not _COMPARE(check.digest()[:TAG_BYTES], view[end:]):
        raise BadTag("HMAC tag does not match")
    packet_kind = _KINDS.get(kind)
    if packet_kind is None:
        raise MalformedPacket(f"unknown packet kind {kind}")
    if not math.isfinite(t_sent):
        raise MalformedPacket("t_sent is not finite")
    body_start = _HEADER_SIZE + sender_len
    raw = data[_HEADER_SIZE:body_start]
    sender = names.get(raw)
    if sender is None:
        sender = decode_id(bytes(raw), "sender id")
        if len(names) >= _MAX_NAMES:
            names.clear()
        names[bytes(raw)] = sender
    return Header(packet_kind, fleet, pn, t_sent, sender), body_start


def _structure_error(
    magic: bytes, version: int, fleet: int, fleet_id: int, sender_len: int, body_len: int,
    n: int,
) -> NoReturn:
    """The first structural check a datagram fails, in the documented order."""
    if magic != MAGIC:
        raise MalformedPacket("bad magic")
    if version != PROTOCOL_VERSION:
        raise UnsupportedVersion(f"protocol version {version}, this code speaks {PROTOCOL_VERSION}")
    if fleet != fleet_id:
        raise WrongFleet(f"fleet id {fleet}, expected {fleet_id}")
    if not 1 <= sender_len <= MAX_ID_BYTES:
        raise MalformedPacket(f"sender id length {sender_len} not in 1..{MAX_ID_BYTES}")
    raise MalformedPacket(
        f"datagram is {n} bytes, header says {OVERHEAD_BYTES + sender_len + body_len}")
