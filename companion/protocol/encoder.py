"""The sending side: messages, reports, commands and status as authenticated datagrams.

Sans-I/O: ``now`` comes in with every call and bytes come out; the caller sends them.
"""

from __future__ import annotations

import math
from typing import Any

from companion.protocol.errors import LocalProtocolError
from companion.protocol.records import ClockEcho, Command, Report, ReportEntry, Status
from companion.protocol.signing import CommandSigner
from companion.protocol.wire import (
    COMMAND_FIXED,
    DATA_FIXED,
    HEADER,
    MAGIC,
    MAX_DATAGRAM_BYTES,
    METADATA_LEN,
    OVERHEAD_BYTES,
    PROTOCOL_VERSION,
    REPORT_FIXED,
    SIGNATURE_BYTES,
    STATUS_FIXED,
    TAG_BYTES,
    U8,
    PacketKind,
    check_key,
    dumps_json,
    encode_id,
    keyed_mac,
    pack_datagram,
)
from utility_specs.message import Message

__all__ = ["Encoder", "message_metadata"]

_MAX_U16 = 0xFFFF
_MAX_U32 = 0xFFFF_FFFF
_MAX_U64 = 0xFFFF_FFFF_FFFF_FFFF


def message_metadata(message: Message) -> dict[str, Any]:
    """The small JSON object that travels in fragment 0 (keys documented in protocol.md)."""
    meta: dict[str, Any] = {"z": message.size}
    if message.data:
        meta["d"] = dict(message.data)
    if message.versions:
        meta["v"] = [[v.name, v.size, v.quality] for v in message.versions]
    if message.version is not None:
        meta["i"] = message.version
    return meta


def _entry_json(entry: ReportEntry) -> list[Any]:
    return [
        entry.sender,
        entry.seq,
        entry.type,
        entry.t_gen,
        entry.t_sent,
        entry.t_rcv,
        entry.size,
        entry.version,
        entry.quality,
        dict(entry.data),
    ]


def _echo_json(echo: ClockEcho) -> list[Any]:
    return [echo.sender, echo.t_sent, echo.t_rcv]


class Encoder:
    """Turns values into datagrams of at most ``max_datagram_bytes`` for one sender.

    Every datagram gets the next packet number of this encoder. The first one is
    ``int(now) << 32``: packet numbers keep increasing across restarts of the sender as long
    as its clock does, so the receivers' replay windows need no handshake.

    Only an encoder given the ground station's ``command_key`` (Ed25519 private seed) can
    encode commands.
    """

    def __init__(
        self,
        fleet_id: int,
        sender: str,
        key: bytes,
        *,
        max_datagram_bytes: int = MAX_DATAGRAM_BYTES,
        command_key: bytes | None = None,
    ) -> None:
        if not 0 <= fleet_id <= _MAX_U32:
            raise LocalProtocolError(f"fleet_id must fit 32 bits, got {fleet_id}")
        self.fleet_id = fleet_id
        self.sender = sender
        self._sender_raw = encode_id(sender, "sender id")
        self._key = check_key(key)
        self.max_datagram_bytes = max_datagram_bytes
        self._body_budget = max_datagram_bytes - OVERHEAD_BYTES - len(self._sender_raw)
        if self._body_budget < DATA_FIXED.size + 64 + METADATA_LEN.size + 64:
            raise LocalProtocolError(f"max_datagram_bytes {max_datagram_bytes} is too small")
        self._next_packet_number: int | None = None
        self._report_number = 0
        self._signer = CommandSigner(command_key) if command_key is not None else None

    def _pack(
        self, kind: PacketKind, body: bytes, now: float, signer: CommandSigner | None = None
    ) -> bytes:
        if not math.isfinite(now):
            raise LocalProtocolError(f"now must be finite, got {now}")
        if self._next_packet_number is None:
            self._next_packet_number = max(0, int(now)) << 32
        packet_number = self._next_packet_number & _MAX_U64
        self._next_packet_number += 1
        return pack_datagram(
            key=self._key,
            kind=kind,
            fleet_id=self.fleet_id,
            packet_number=packet_number,
            t_sent=now,
            sender_raw=self._sender_raw,
            body=body,
            sign=signer.sign if signer is not None else None,
        )

    def fragment(self, message: Message, payload: bytes, now: float) -> list[bytes]:
        """All DATA datagrams of one message; losing any of them loses the message.

        Fragment 0 carries the metadata (``message_metadata``), then as much payload as
        fits; the others carry payload only.
        """
        if message.sender != self.sender:
            raise LocalProtocolError(
                f"message sender {message.sender!r} is not this encoder's {self.sender!r}"
            )
        if not 0 <= message.seq <= _MAX_U32:
            raise LocalProtocolError(f"seq must fit 32 bits, got {message.seq}")
        type_raw = encode_id(message.type, "message type")
        metadata = dumps_json(message_metadata(message), "message metadata")
        capacity = self._body_budget - DATA_FIXED.size - len(type_raw)
        first_capacity = capacity - METADATA_LEN.size - len(metadata)
        if first_capacity < 0:
            raise LocalProtocolError(
                f"metadata of {len(metadata)} bytes does not fit in one datagram "
                f"(at most {capacity - METADATA_LEN.size} here)"
            )
        total = len(payload)
        if total > _MAX_U32:
            raise LocalProtocolError(f"payload of {total} bytes is too large")
        rest = max(0, total - first_capacity)
        count = 1 + -(-rest // capacity)
        if count > _MAX_U16:
            raise LocalProtocolError(f"payload of {total} bytes needs {count} > 65535 fragments")
        if not math.isfinite(now):
            raise LocalProtocolError(f"now must be finite, got {now}")
        if self._next_packet_number is None:
            self._next_packet_number = max(0, int(now)) << 32
        first_pn = self._next_packet_number
        self._next_packet_number += count
        # what pack_datagram does per datagram, inlined: a fleet sends ~27 per 30 KB image
        view = memoryview(payload)
        sender_raw, mac = self._sender_raw, keyed_mac(self._key)
        header_pack, fixed_pack = HEADER.pack, DATA_FIXED.pack
        seq, t_gen, type_len = message.seq, message.t_gen, len(type_raw)
        lead = DATA_FIXED.size + type_len
        meta = METADATA_LEN.pack(len(metadata)) + metadata
        datagrams = []
        start = 0
        for index in range(count):
            end = min(total, start + (first_capacity if index == 0 else capacity))
            extra = meta if index == 0 else b""
            signed = b"".join((
                header_pack(MAGIC, PROTOCOL_VERSION, PacketKind.DATA, self.fleet_id,
                            (first_pn + index) & _MAX_U64, now,
                            lead + len(extra) + end - start, len(sender_raw)),
                sender_raw,
                fixed_pack(seq, t_gen, index, count, total, type_len),
                type_raw,
                extra,
                view[start:end],
            ))
            check = mac.copy()
            check.update(signed)
            datagrams.append(signed + check.digest()[:TAG_BYTES])
            start = end
        return datagrams

    def encode_report(self, report: Report, now: float) -> list[bytes]:
        """One report as one or more self-contained datagrams.

        Echoes go first (part 0 while they fit, then on into the next parts), then entries:
        any number of echoes and entries fits, each part is a complete JSON object.
        """
        self._report_number = self._report_number % _MAX_U32 + 1
        budget = self._body_budget - REPORT_FIXED.size
        echoes = [dumps_json(_echo_json(e), "clock echo") for e in report.echoes]
        entries = [dumps_json(_entry_json(e), "report entry") for e in report.entries]
        # {"e":[...],"c":[...]}: 15 bytes of structure around the two lists.
        parts: list[tuple[list[bytes], list[bytes]]] = []
        current: tuple[list[bytes], list[bytes]] = ([], [])
        used = 15
        for which, raws in ((1, echoes), (0, entries)):
            for raw in raws:
                if 15 + len(raw) > budget:
                    what = "clock echo" if which else "report entry"
                    raise LocalProtocolError(f"{what} of {len(raw)} bytes does not fit")
                extra = len(raw) + (1 if current[which] else 0)
                if used + extra > budget:
                    parts.append(current)
                    current, used = ([], []), 15
                    extra = len(raw)
                current[which].append(raw)
                used += extra
        parts.append(current)
        if len(parts) > _MAX_U16:
            raise LocalProtocolError("report too large")
        datagrams = []
        for index, (chunk, echo_chunk) in enumerate(parts):
            body = (
                REPORT_FIXED.pack(self._report_number, index, len(parts))
                + b'{"e":['
                + b",".join(chunk)
                + b'],"c":['
                + b",".join(echo_chunk)
                + b"]}"
            )
            datagrams.append(self._pack(PacketKind.REPORT, body, now))
        return datagrams

    def encode_command(self, command: Command, now: float, *, epoch: int = 0) -> bytes:
        """One signed COMMAND datagram (ground -> one drone).

        ``epoch`` is the boot epoch the target drone announced (0 while unknown): a drone
        obeys only commands carrying its current epoch, so a capture replayed after it
        restarted is refused (docs/protocol.md).
        """
        if self._signer is None:
            raise LocalProtocolError("only an encoder with the ground station's command key "
                                     "can encode commands")
        if not 0 <= epoch <= _MAX_U64:
            raise LocalProtocolError(f"epoch must fit 64 bits, got {epoch}")
        name = encode_id(command.name, "command name")
        target = encode_id(command.target or "", "command target", allow_empty=True)
        args = dumps_json(dict(command.args), "command args")
        body = (
            COMMAND_FIXED.pack(epoch, command.command_id, command.t_exec, len(name))
            + name
            + U8.pack(len(target))
            + target
            + args
        )
        if len(body) + SIGNATURE_BYTES > self._body_budget:
            raise LocalProtocolError(f"command of {len(body)} bytes does not fit one datagram")
        return self._pack(PacketKind.COMMAND, body, now, self._signer)

    def encode_status(self, status: Status, now: float) -> bytes:
        """One STATUS datagram (drone -> ground): an acknowledgement or a status."""
        state = encode_id(status.state, "status state")
        info = dumps_json(dict(status.info), "status info")
        body = STATUS_FIXED.pack(status.command_id or 0, len(state)) + state + info
        if len(body) > self._body_budget:
            raise LocalProtocolError(f"status of {len(body)} bytes does not fit one datagram")
        return self._pack(PacketKind.STATUS, body, now)
