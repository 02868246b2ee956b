"""The receiving side: authenticate, reject replays, reassemble, hand out events.

Sans-I/O in the aioquic shape: ``receive_datagram(data, addr, now)`` and
``handle_timer(now)`` go in; ``next_event()`` and ``get_timer()`` come out. Bad input never
escapes: every ``RemoteProtocolError`` is caught in ``receive_datagram``, counted under its
reason in ``counters`` and turned into a ``PacketDropped`` event. Memory is bounded by
``DecoderLimits`` whatever arrives.
"""

from __future__ import annotations

import hmac
import math
import struct
from collections import OrderedDict, deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

from companion.protocol.errors import (
    BadSignature,
    BadTag,
    MalformedPacket,
    OversizePacket,
    RemoteProtocolError,
    ReplayedPacket,
    StalePacket,
    WrongEpoch,
)
from companion.protocol.events import (
    Address,
    CommandReceived,
    Event,
    MessageExpired,
    MessageReassembled,
    PacketDropped,
    ReportReceived,
    StatusReceived,
)
from companion.protocol.records import ClockEcho, Command, Report, ReportEntry, Status
from companion.protocol.signing import CommandVerifier
from companion.protocol.wire import (
    COMMAND_FIXED,
    DATA_FIXED,
    HEADER,
    MAGIC,
    MAX_DATAGRAM_BYTES,
    MAX_ID_BYTES,
    METADATA_LEN,
    OVERHEAD_BYTES,
    PROTOCOL_VERSION,
    REPORT_FIXED,
    SIGNATURE_BYTES,
    STATUS_FIXED,
    TAG_BYTES,
    U8,
    Header,
    PacketKind,
    check_key,
    decode_id,
    keyed_mac,
    loads_json_object,
    unpack_header,
)
from utility_specs.errors import MessageError
from utility_specs.message import Message, Version

__all__ = ["COUNTER_NAMES", "Decoder", "DecoderLimits"]

COUNTER_NAMES = (
    "datagrams",
    "accepted",
    "malformed",
    "unsupported_version",
    "wrong_fleet",
    "bad_tag",
    "bad_signature",
    "wrong_epoch",
    "stale",
    "replayed",
    "oversize",
    "duplicate_fragment",
    "late_fragment",
    "messages",
    "expired",
    "evicted",
    "reports",
    "commands",
    "statuses",
    "events_overflow",
)
"""Every key of ``Decoder.counters`` (all start at 0)."""

_DATA_FIXED_UNPACK = DATA_FIXED.unpack_from
_DATA_FIXED_SIZE = DATA_FIXED.size
_METADATA_LEN_UNPACK = METADATA_LEN.unpack_from
_MAX_NAMES = 1024
_HEADER_UNPACK = HEADER.unpack_from
_HEADER_SIZE = HEADER.size
_OVERHEAD_BYTES = OVERHEAD_BYTES
_DATA = int(PacketKind.DATA)
_COMPARE = hmac.compare_digest

MessageKey = tuple[str, int, float]
"""(sender, seq, t_gen): t_gen tells a restarted sender's seq 0 from the previous run's."""


@dataclass(frozen=True, slots=True, kw_only=True)
class DecoderLimits:
    """The bounds that keep a decoder's memory and work finite (defaults in protocol.md)."""

    max_datagram_bytes: int = MAX_DATAGRAM_BYTES
    max_message_bytes: int = 1 << 20
    """Largest reassembled payload, bytes."""
    max_fragments: int = 1024
    """Most fragments one message may declare."""
    max_partials: int = 64
    """Most messages being reassembled at once; the least recently active is evicted."""
    max_buffered_bytes: int = 8 << 20
    """Most payload and metadata bytes held by all partial messages together."""
    reassembly_timeout_s: float = 3.0
    """A partial message expires this long after its latest fragment arrived."""
    max_clock_skew_s: float | None = 30.0
    """Largest accepted |t_sent - now|; ``None`` turns the staleness check off."""
    replay_window: int = 4096
    """Packets per sender that may arrive out of order before counting as replayed."""
    max_senders: int = 256
    """Senders whose replay state is kept (least recently heard evicted)."""
    max_pending_events: int = 10_000
    """Events kept for ``next_event``; beyond this a drop notice is discarded first, then the
    oldest event (counted in ``events_overflow``)."""
    recent_messages: int = 4096
    """Completed or expired messages remembered so their late fragments are dropped."""

    def __post_init__(self) -> None:
        for name in (
            "max_datagram_bytes",
            "max_message_bytes",
            "max_fragments",
            "max_partials",
            "max_buffered_bytes",
            "replay_window",
            "max_senders",
            "max_pending_events",
            "recent_messages",
        ):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.max_buffered_bytes < self.max_message_bytes:
            raise ValueError("max_buffered_bytes must be >= max_message_bytes")
        if not self.reassembly_timeout_s > 0:
            raise ValueError(f"reassembly_timeout_s must be > 0, got {self.reassembly_timeout_s}")
        if self.max_clock_skew_s is not None and not self.max_clock_skew_s > 0:
            raise ValueError(f"max_clock_skew_s must be > 0 or None, got {self.max_clock_skew_s}")


class _Reader:
    """Sequential reads from an authenticated body; running short is a MalformedPacket."""

    __slots__ = ("_offset", "_view")

    def __init__(self, view: memoryview) -> None:
        self._view = view
        self._offset = 0

    def unpack(self, fmt: struct.Struct) -> tuple[Any, ...]:
        if self._offset + fmt.size > len(self._view):
            raise MalformedPacket("body too short")
        values = fmt.unpack_from(self._view, self._offset)
        self._offset += fmt.size
        return values

    def take(self, n: int) -> bytes:
        if self._offset + n > len(self._view):
            raise MalformedPacket("body too short")
        raw = bytes(self._view[self._offset : self._offset + n])
        self._offset += n
        return raw

    def rest(self) -> bytes:
        raw = bytes(self._view[self._offset :])
        self._offset = len(self._view)
        return raw

    def short_id(self, length: int, what: str) -> str:
        if not 1 <= length <= MAX_ID_BYTES:
            raise MalformedPacket(f"{what} length {length} not in 1..{MAX_ID_BYTES}")
        return decode_id(self.take(length), what)


@dataclass(slots=True)
class _ReplayWindow:
    """RFC 4303 sec. 3.4.3-style sliding window over one sender's packet numbers."""

    highest: int
    seen: int
    """Bit i set: packet number ``highest - i`` was accepted."""
    last_accept: float
    offset_max: float = -math.inf
    """Largest ``t_sent - now`` accepted: the sender's clock offset minus the smallest delay,
    so ``now + offset_max`` bounds the ``t_sent`` of anything it sent before ``now``."""


@dataclass(frozen=True, slots=True)
class _Floor:
    """After a restart: what a sender may have had accepted by the previous process."""

    packet_number: int
    t_sent: float
    """Datagrams sent (sender's clock) at or before this are refused."""
    offset: float
    expires: float


@dataclass(slots=True)
class _Partial:
    key: MessageKey
    type: str
    count: int
    total: int
    deadline: float
    chunks: list[memoryview | None]
    """Per fragment index: its payload, a view into the authenticated datagram (no copy
    until the one ``join`` that builds the message)."""
    received: int = 0
    buffered: int = 0
    """Payload plus metadata bytes held."""
    payload_bytes: int = 0
    prototype: Message | None = None


def _number(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise MalformedPacket(f"{what} must be a number")
    try:
        result = float(value)
    except OverflowError as exc:  # a JSON integer with hundreds of digits
        raise MalformedPacket(f"{what} is out of range") from exc
    if not math.isfinite(result):
        raise MalformedPacket(f"{what} must be finite")
    return result


MAX_SIZE = 0xFFFF_FFFF
"""Largest message or version size, bytes (the wire's 32-bit total length)."""


def _integer(value: Any, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise MalformedPacket(f"{what} must be an integer")
    return value


def _count(value: Any, what: str, *, most: int = MAX_SIZE) -> int:
    """A size, index or sequence number: an integer in 0..``most``."""
    result = _integer(value, what)
    if not 0 <= result <= most:
        raise MalformedPacket(f"{what} {result} not in 0..{most}")
    return result


def _string(value: Any, what: str) -> str:
    if not isinstance(value, str):
        raise MalformedPacket(f"{what} must be a string")
    return value


def _object(value: Any, what: str) -> Mapping[str, Any]:
    if not isinstance(value, dict):
        raise MalformedPacket(f"{what} must be a JSON object")
    return value


class Decoder:
    """Decodes every packet kind for one fleet.

    ``local_id`` becomes ``receiver`` of reassembled messages (the ground station's id).
    """

    def __init__(
        self,
        fleet_id: int,
        key: bytes,
        *,
        local_id: str | None = None,
        limits: DecoderLimits | None = None,
        command_key: bytes | None = None,
        epoch: int | None = None,
    ) -> None:
        """``command_key``: the ground station's Ed25519 public key; without it every COMMAND
        is dropped. ``epoch``: this boot's epoch; commands for another one are dropped."""
        self.fleet_id = fleet_id
        self._key = check_key(key)
        self.local_id = local_id
        self.limits = limits or DecoderLimits()
        self.counters: dict[str, int] = dict.fromkeys(COUNTER_NAMES, 0)
        self._events: deque[Event] = deque()
        self._queued_drops = 0
        """How many of ``_events`` are PacketDropped (they give way first on overflow)."""
        self._partials: OrderedDict[MessageKey, _Partial] = OrderedDict()
        self._buffered = 0
        self._recent: OrderedDict[MessageKey, None] = OrderedDict()
        self._windows: OrderedDict[str, _ReplayWindow] = OrderedDict()
        # commands get their own windows: data under the fleet key (which every drone holds)
        # must not be able to push the window of the station's signed commands
        self._command_windows: OrderedDict[str, _ReplayWindow] = OrderedDict()
        self._verifier = CommandVerifier(command_key) if command_key is not None else None
        self.epoch = epoch
        self._floors: dict[str, _Floor] = {}
        self._window_mask = (1 << self.limits.replay_window) - 1
        self._mac = keyed_mac(self._key)
        self._names: dict[bytes, str] = {}
        """Authenticated sender ids and message types, raw -> decoded (bounded)."""

    # -- outputs -------------------------------------------------------------------------

    @property
    def buffered_bytes(self) -> int:
        """Payload and metadata bytes held by partial messages now."""
        return self._buffered

    @property
    def partial_count(self) -> int:
        return len(self._partials)

    @property
    def sender_count(self) -> int:
        """Senders with replay state."""
        return len(self._windows)

    def next_event(self) -> Event | None:
        """The oldest pending event, or ``None``."""
        if not self._events:
            return None
        event = self._events.popleft()
        if isinstance(event, PacketDropped):
            self._queued_drops -= 1
        return event

    def get_timer(self) -> float | None:
        """Absolute time of the next reassembly timeout, or ``None`` without partials."""
        if not self._partials:
            return None
        return min(p.deadline for p in self._partials.values())

    # -- inputs --------------------------------------------------------------------------

    def handle_timer(self, now: float) -> None:
        """Expire every partial message whose deadline is at or before ``now``."""
        for key in [k for k, p in self._partials.items() if p.deadline <= now]:
            self._discard(key, evicted=False)

    def receive_datagram(self, data: bytes, addr: Address, now: float) -> None:
        """Take one UDP payload; results come out of ``next_event``."""
        self.receive_datagrams(((data, addr),), now)

    def receive_datagrams(self, datagrams: Sequence[tuple[bytes, Address]], now: float) -> None:
        """Take a burst of UDP payloads that arrived together (what one socket read-ready
        drains); the same as :meth:`receive_datagram` on each, in order.

        This is a ground station's hot loop (13,500 datagrams/s at 50 drones x 10 images/s):
        a DATA datagram from a sender heard before, in order, takes the inlined path below
        (the same checks in the same order as :meth:`_receive_one`, without a call per
        check); everything else, including every error, goes through :meth:`_receive_one`.
        """
        counters = self.counters
        counters["datagrams"] += len(datagrams)
        limits = self.limits
        max_bytes = limits.max_datagram_bytes
        fleet_id = self.fleet_id
        mac = self._mac
        names = self._names
        windows = self._windows
        skew = limits.max_clock_skew_s
        forget_after = math.inf if skew is None else 2 * skew
        replay_bits = limits.replay_window
        mask = self._window_mask
        receive_data = self._receive_data
        for data, addr in datagrams:
            try:
                if type(data) is not bytes:  # the body is kept as views: no mutable buffer
                    data = bytes(data)
                n = len(data)
                if n > max_bytes or n <= _OVERHEAD_BYTES or self._floors:
                    self._receive_one(data, addr, now)
                    continue
                magic, version, kind, fleet, pn, t_sent, body_len, sender_len = (
                    _HEADER_UNPACK(data, 0))
                if (kind != _DATA or magic != MAGIC or version != PROTOCOL_VERSION
                        or fleet != fleet_id or not 1 <= sender_len <= MAX_ID_BYTES
                        or n != _OVERHEAD_BYTES + sender_len + body_len):
                    self._receive_one(data, addr, now)
                    continue
                end = n - TAG_BYTES
                view = memoryview(data)
                check = mac.copy()
                check.update(view[:end])
                if not _COMPARE(check.digest()[:TAG_BYTES], view[end:]):
                    raise BadTag("HMAC tag does not match")
                start = _HEADER_SIZE + sender_len
                sender = names.get(data[_HEADER_SIZE:start])
                if sender is None or not math.isfinite(t_sent):
                    self._receive_one(data, addr, now)  # first datagram of a sender
                    continue
                if skew is not None and abs(t_sent - now) > skew:
                    self._check_fresh(t_sent, now, sender)
                window = windows.get(sender)
                if (window is not None and pn > window.highest
                        and now - window.last_accept <= forget_after):
                    shift = pn - window.highest
                    window.seen = (((window.seen << shift) | 1) & mask
                                   if shift < replay_bits else 1)
                    window.highest = pn
                    window.last_accept = now
                    if t_sent - now > window.offset_max:
                        window.offset_max = t_sent - now
                    windows.move_to_end(sender)
                else:
                    self._check_replay(Header(PacketKind.DATA, fleet, pn, t_sent, sender),
                                       now, windows)
                counters["accepted"] += 1
                receive_data(sender, t_sent, view[start:end], addr, now)
            except RemoteProtocolError as exc:
                self._refuse(exc, addr)

    def _receive_one(self, data: bytes, addr: Address, now: float) -> None:
        """Every check, for any kind of datagram (errors escape to the caller)."""
        header, start = unpack_header(
            data,
            mac=self._mac,
            fleet_id=self.fleet_id,
            max_datagram_bytes=self.limits.max_datagram_bytes,
            names=self._names,
        )
        body = memoryview(data)[start : len(data) - TAG_BYTES]
        kind = header.kind
        windows = self._windows
        if kind is PacketKind.COMMAND:
            body = self._verify_command(data, body)
            windows = self._command_windows
        if self._floors:
            self._check_floor(header, now)
        self._check_fresh(header.t_sent, now, header.sender)
        self._check_replay(header, now, windows)
        self.counters["accepted"] += 1
        if kind is PacketKind.DATA:
            self._receive_data(header.sender, header.t_sent, body, addr, now)
        elif kind is PacketKind.REPORT:
            self._receive_report(header, _Reader(body), addr, now)
        elif kind is PacketKind.COMMAND:
            self._receive_command(header, _Reader(body), addr, now)
        else:
            self._receive_status(header, _Reader(body), addr, now)

    # -- checks --------------------------------------------------------------------------

    def _check_fresh(self, t_sent: float, now: float, sender: str | None = None) -> None:
        skew = self.limits.max_clock_skew_s
        if skew is not None and abs(t_sent - now) > skew:
            raise StalePacket(
                f"t_sent {t_sent:.3f} is {t_sent - now:+.3f} s from now "
                f"(allowed ±{skew} s)", sender=sender, skew_s=t_sent - now
            )

    def _verify_command(self, data: bytes, body: memoryview) -> memoryview:
        """The command body without its signature, once the signature is verified."""
        if self._verifier is None:
            raise BadSignature("commands are not accepted here (no command key)")
        if len(body) < SIGNATURE_BYTES:
            raise BadSignature("command has no signature")
        start = len(data) - TAG_BYTES - SIGNATURE_BYTES
        view = memoryview(data)
        if not self._verifier.verify(view[:start], view[start : start + SIGNATURE_BYTES]):
            raise BadSignature("command signature does not verify with the command key")
        return body[: len(body) - SIGNATURE_BYTES]

    def _check_floor(self, header: Header, now: float) -> None:
        floor = self._floors.get(header.sender)
        if floor is None:
            return
        if now > floor.expires:
            del self._floors[header.sender]
            return
        if header.packet_number <= floor.packet_number or header.t_sent <= floor.t_sent:
            raise ReplayedPacket(
                f"packet {header.packet_number} sent at {header.t_sent:.3f} may have been "
                "accepted before this receiver restarted"
            )

    def replay_state(self, now: float) -> dict[str, list[float]]:
        """What a restarted receiver needs to refuse replays: per sender heard recently,
        ``[highest packet number, t, now]`` where ``t - now`` is the largest clock offset
        (``t_sent - t_rcv``) accepted from it (JSON-ready)."""
        skew = self.limits.max_clock_skew_s
        horizon = -math.inf if skew is None else now - 2 * skew
        known: dict[str, tuple[int, float]] = {
            sender: (floor.packet_number, floor.offset)
            for sender, floor in self._floors.items() if floor.expires >= now
        }
        for windows in (self._windows, self._command_windows):
            for sender, window in windows.items():
                if window.last_accept < horizon or not math.isfinite(window.offset_max):
                    continue
                pn, offset = known.get(sender, (-1, -math.inf))
                known[sender] = (max(pn, window.highest), max(offset, window.offset_max))
        # [pn, t_sent, at]: t_sent - at is the offset (the file keeps that self-evident form)
        return {sender: [pn, now + offset, now] for sender, (pn, offset) in known.items()}

    def restore_replay_state(
        self, state: Mapping[str, Any], now: float, *, slack_s: float = 1.0,
        closed: bool = False,
    ) -> int:
        """Refuse, per sender of ``state`` (from :meth:`replay_state` of the previous
        process), every datagram sent before ``now`` on that sender's clock, plus ``slack_s``
        for delay jitter. The clock offset comes from the saved ``t_sent`` and acceptance
        time, so the rule holds however long ago the state was saved. Returns the count.

        ``closed``: the state was taken when the previous process stopped accepting (a clean
        shutdown, not a crash between two saves), so its highest packet numbers are exact and
        they alone are refused: what a drone sent while the receiver was down, or in its
        first second back, was never accepted, and refusing it lost real data and raised
        ``replayed`` alerts after every ordinary restart.
        """
        skew = self.limits.max_clock_skew_s
        lifetime = math.inf if skew is None else 2 * skew + slack_s
        restored = 0
        for sender, entry in state.items():
            if not (isinstance(sender, str) and isinstance(entry, list) and len(entry) == 3
                    and all(isinstance(v, int | float) and not isinstance(v, bool)
                            and math.isfinite(v) for v in entry)):
                continue
            pn, t_sent, accepted_at = entry
            if skew is not None and now - accepted_at > 2 * skew:
                continue  # everything it sent then is stale now
            offset = t_sent - accepted_at
            self._floors[sender] = _Floor(packet_number=int(pn),
                                          t_sent=-math.inf if closed
                                          else now + offset + slack_s, offset=offset,
                                          expires=now + lifetime)
            restored += 1
        return restored

    def _check_replay(
        self, header: Header, now: float, windows: OrderedDict[str, _ReplayWindow]
    ) -> None:
        pn = header.packet_number
        window = windows.get(header.sender)
        skew = self.limits.max_clock_skew_s
        if window is not None and skew is not None and now - window.last_accept > 2 * skew:
            # Every packet accepted before is stale by now, so forgetting is safe, and it
            # lets a sender whose clock went back (reboot without RTC) be heard again.
            window = None
        if window is None:
            if len(windows) >= self.limits.max_senders and header.sender not in windows:
                windows.popitem(last=False)
            windows[header.sender] = _ReplayWindow(
                highest=pn, seen=1, last_accept=now, offset_max=header.t_sent - now
            )
            windows.move_to_end(header.sender)
            return
        size = self.limits.replay_window
        if pn > window.highest:
            shift = pn - window.highest
            window.seen = ((window.seen << shift) | 1) if shift < size else 1
            window.seen &= self._window_mask
            window.highest = pn
        else:
            offset = window.highest - pn
            if offset >= size:
                raise ReplayedPacket(f"packet number {pn} is older than the replay window")
            if window.seen >> offset & 1:
                raise ReplayedPacket(f"packet number {pn} already received")
            window.seen |= 1 << offset
        window.last_accept = now
        if header.t_sent - now > window.offset_max:
            window.offset_max = header.t_sent - now
        windows.move_to_end(header.sender)

    # -- DATA ----------------------------------------------------------------------------

    def _receive_data(
        self, sender: str, t_sent: float, body: memoryview, addr: Address, now: float
    ) -> None:
        """One DATA fragment. The per-datagram hot path of a ground station (27 per 30 KB
        image): reads with precompiled structs straight from the body, keeps the payload as
        a view, and builds nothing per fragment but the reassembly key."""
        limits = self.limits
        size = len(body)
        if size < _DATA_FIXED_SIZE:
            raise MalformedPacket("body too short")
        seq, t_gen, index, count, total, type_len = _DATA_FIXED_UNPACK(body, 0)
        if not 1 <= type_len <= MAX_ID_BYTES:
            raise MalformedPacket(f"message type length {type_len} not in 1..{MAX_ID_BYTES}")
        offset = _DATA_FIXED_SIZE + type_len
        if offset > size:
            raise MalformedPacket("body too short")
        type_raw = body[_DATA_FIXED_SIZE:offset]
        msg_type: str | None = self._names.get(type_raw)  # type: ignore[call-overload]
        if msg_type is None:
            msg_type = self._name(type_raw, "message type")
        if not math.isfinite(t_gen):
            raise MalformedPacket("t_gen is not finite")
        if not 0 <= index < count:
            raise MalformedPacket(f"fragment index {index} not in 0..{count - 1}")
        if count > limits.max_fragments:
            raise OversizePacket(f"{count} fragments > {limits.max_fragments}")
        if total > limits.max_message_bytes:
            raise OversizePacket(f"message of {total} bytes > {limits.max_message_bytes}")
        meta_len = 0
        metadata = b""
        if index == 0:
            if offset + 2 > size:
                raise MalformedPacket("body too short")
            (meta_len,) = _METADATA_LEN_UNPACK(body, offset)
            offset += 2
            if offset + meta_len > size:
                raise MalformedPacket("body too short")
            metadata = bytes(body[offset : offset + meta_len])
            offset += meta_len
        chunk = body[offset:]
        chunk_len = size - offset
        if chunk_len > total:
            raise MalformedPacket(f"fragment of {chunk_len} bytes > message of {total}")
        key: MessageKey = (sender, seq, t_gen)
        if key in self._recent:
            self._drop("late_fragment", str(key), addr)
            return
        partial = self._partials.get(key)
        # the metadata is parsed once, after the late check; a lone fragment is the message
        prototype = None
        if index == 0:
            prototype = self._prototype(sender, t_sent, seq, msg_type, t_gen, metadata,
                                        t_rcv=max(now, t_gen) if count == 1 else None)
        if count == 1:
            if chunk_len != total or prototype is None:
                raise MalformedPacket("single fragment does not hold the whole message")
            self._emit_message(prototype, bytes(chunk), addr, now, fragments=1)
            self._remember(key)
            return
        if partial is None:
            partial = self._new_partial(key, msg_type, count, total, now)
        elif partial.count != count or partial.total != total or partial.type != msg_type:
            self._discard(key, evicted=False)
            raise MalformedPacket(f"fragment of {key} disagrees with the earlier ones")
        chunks = partial.chunks
        if chunks[index] is not None:
            self._drop("duplicate_fragment", str(key), addr)
            return
        if partial.payload_bytes + chunk_len > total:
            self._discard(key, evicted=False)
            raise MalformedPacket(f"fragments of {key} exceed the declared {total} bytes")
        cost = chunk_len + meta_len
        chunks[index] = chunk
        partial.received += 1
        partial.buffered += cost
        partial.payload_bytes += chunk_len
        self._buffered += cost
        partial.deadline = now + limits.reassembly_timeout_s
        self._partials.move_to_end(key)
        if prototype is not None:
            partial.prototype = prototype
        if self._buffered > limits.max_buffered_bytes:
            self._enforce_buffer_bound(keep=key)
            if key not in self._partials:
                return
        if partial.received == count:
            # one copy: the views of the datagrams straight into the message's bytes
            payload = b"".join(chunks)  # type: ignore[arg-type]  # all set: received == count
            self._release(key)
            self._remember(key)
            if len(payload) != partial.total or partial.prototype is None:
                raise MalformedPacket(f"fragments of {key} add up to {len(payload)} bytes")
            message = replace(partial.prototype, t_rcv=max(now, partial.prototype.t_gen))
            self._emit_message(message, payload, addr, now, fragments=count)

    def _name(self, raw: memoryview, what: str) -> str:
        """Decode a short authenticated identifier (message type) and remember it, so the
        next datagrams find it in ``_names`` (a memoryview hashes and compares as its bytes)."""
        name = decode_id(bytes(raw), what)
        if len(self._names) >= _MAX_NAMES:
            self._names.clear()
        self._names[bytes(raw)] = name
        return name

    def _prototype(
        self, sender: str, t_sent: float, seq: int, msg_type: str, t_gen: float, raw: bytes,
        *, t_rcv: float | None,
    ) -> Message:
        meta = loads_json_object(raw, "message metadata")
        size = _count(meta.get("z", 0), "metadata size")
        data = _object(meta.get("d", {}), "metadata data")
        try:
            versions = _versions(meta.get("v", []))
            version = meta.get("i")
            return Message(
                sender=sender,
                seq=seq,
                type=msg_type,
                t_gen=t_gen,
                size=size,
                receiver=self.local_id,
                t_sent=t_sent,
                t_rcv=t_rcv,
                data=data,
                versions=versions,
                version=None if version is None else _count(version, "metadata version"),
            )
        except MessageError as exc:
            raise MalformedPacket(f"metadata describes an invalid message: {exc}") from exc

    def _new_partial(
        self, key: MessageKey, msg_type: str, count: int, total: int, now: float
    ) -> _Partial:
        while len(self._partials) >= self.limits.max_partials:
            oldest = next(iter(self._partials))
            self._discard(oldest, evicted=True)
        partial = _Partial(
            key=key,
            type=msg_type,
            count=count,
            total=total,
            deadline=now + self.limits.reassembly_timeout_s,
            chunks=[None] * count,
        )
        self._partials[key] = partial
        return partial

    def _enforce_buffer_bound(self, *, keep: MessageKey) -> None:
        """Evict the least recently active partials (``keep`` last) until under the bound."""
        while self._buffered > self.limits.max_buffered_bytes:
            victim = next((k for k in self._partials if k != keep), keep)
            self._discard(victim, evicted=True)

    def _emit_message(
        self, message: Message, payload: bytes, addr: Address, now: float, *, fragments: int
    ) -> None:
        self.counters["messages"] += 1
        self._emit(
            MessageReassembled(
                message=message, payload=payload, addr=addr, t_rcv=now, fragments=fragments
            )
        )

    def _release(self, key: MessageKey) -> _Partial:
        partial = self._partials.pop(key)
        self._buffered -= partial.buffered
        return partial

    def _discard(self, key: MessageKey, *, evicted: bool) -> None:
        partial = self._release(key)
        self._remember(key)
        self.counters["evicted" if evicted else "expired"] += 1
        sender, seq, _ = key
        self._emit(
            MessageExpired(
                sender=sender,
                seq=seq,
                type=partial.type,
                fragments_missing=partial.count - partial.received,
                fragment_count=partial.count,
                evicted=evicted,
            )
        )

    def _remember(self, key: MessageKey) -> None:
        self._recent[key] = None
        self._recent.move_to_end(key)
        while len(self._recent) > self.limits.recent_messages:
            self._recent.popitem(last=False)

    # -- REPORT, COMMAND, STATUS ---------------------------------------------------------

    def _receive_report(self, header: Header, reader: _Reader, addr: Address, now: float) -> None:
        number, part, count = reader.unpack(REPORT_FIXED)
        if not part < count:
            raise MalformedPacket(f"report part {part} not in 0..{count - 1}")
        body = loads_json_object(reader.rest(), "report")
        entries_raw = body.get("e", [])
        echoes_raw = body.get("c", [])
        if not isinstance(entries_raw, list) or not isinstance(echoes_raw, list):
            raise MalformedPacket("report entries and echoes must be lists")
        try:
            entries = tuple(_report_entry(e) for e in entries_raw)
            echoes = tuple(_clock_echo(e) for e in echoes_raw)
        except ValueError as exc:
            raise MalformedPacket(f"invalid report: {exc}") from exc
        self.counters["reports"] += 1
        self._emit(
            ReportReceived(
                report=Report(entries=entries, echoes=echoes),
                reporter=header.sender,
                report_number=number,
                part_index=part,
                part_count=count,
                t_sent=header.t_sent,
                t_rcv=now,
                addr=addr,
            )
        )

    def _receive_command(self, header: Header, reader: _Reader, addr: Address, now: float) -> None:
        epoch, command_id, t_exec, name_len = reader.unpack(COMMAND_FIXED)
        if self.epoch is not None and epoch != self.epoch:
            raise WrongEpoch(f"command for epoch {epoch}, this boot is {self.epoch}")
        name = reader.short_id(name_len, "command name")
        (target_len,) = reader.unpack(U8)
        target = reader.short_id(target_len, "command target") if target_len else None
        args = loads_json_object(reader.rest(), "command args")
        try:
            command = Command(
                command_id=command_id, name=name, t_exec=t_exec, args=args, target=target
            )
        except ValueError as exc:
            raise MalformedPacket(f"invalid command: {exc}") from exc
        self.counters["commands"] += 1
        self._emit(
            CommandReceived(
                command=command, sender=header.sender, t_sent=header.t_sent, t_rcv=now, addr=addr
            )
        )

    def _receive_status(self, header: Header, reader: _Reader, addr: Address, now: float) -> None:
        command_id, state_len = reader.unpack(STATUS_FIXED)
        state = reader.short_id(state_len, "status state")
        info = loads_json_object(reader.rest(), "status info")
        status = Status(state=state, command_id=command_id or None, info=info)
        self.counters["statuses"] += 1
        self._emit(
            StatusReceived(
                status=status, sender=header.sender, t_sent=header.t_sent, t_rcv=now, addr=addr
            )
        )

    # -- plumbing ------------------------------------------------------------------------

    def _refuse(self, exc: RemoteProtocolError, addr: Address) -> None:
        """Count and tell a refused datagram (with its sender and skew when stale)."""
        if isinstance(exc, StalePacket):
            self._drop(exc.reason, str(exc), addr, sender=exc.sender, skew_s=exc.skew_s)
        else:
            self._drop(exc.reason, str(exc), addr)

    def _drop(self, reason: str, detail: str, addr: Address, *, sender: str | None = None,
              skew_s: float | None = None) -> None:
        self.counters[reason] = self.counters.get(reason, 0) + 1
        self._emit(PacketDropped(reason=reason, detail=detail, addr=addr, sender=sender,
                                 skew_s=skew_s))

    def _emit(self, event: Event) -> None:
        """Queue ``event``. When the queue is full, a drop notice gives way before anything
        delivered: a flood of forged datagrams in one batch must not push an authenticated
        message's event out (its drops stay counted in ``counters`` either way)."""
        events = self._events
        dropped = isinstance(event, PacketDropped)
        if len(events) >= self.limits.max_pending_events:
            self.counters["events_overflow"] += 1
            if dropped:
                return
            if self._queued_drops:
                for i, old in enumerate(events):
                    if isinstance(old, PacketDropped):
                        del events[i]
                        self._queued_drops -= 1
                        break
            else:
                events.popleft()
        events.append(event)
        if dropped:
            self._queued_drops += 1


def _versions(raw: Any) -> tuple[Version, ...]:
    if not isinstance(raw, list):
        raise MalformedPacket("metadata versions must be a list")
    versions = []
    for item in raw:
        if not isinstance(item, list) or len(item) != 3:
            raise MalformedPacket("metadata version must be [name, size, quality]")
        versions.append(
            Version(
                name=_string(item[0], "version name"),
                size=_count(item[1], "version size"),
                quality=_number(item[2], "version quality"),
            )
        )
    return tuple(versions)


def _clock_echo(raw: Any) -> ClockEcho:
    if not isinstance(raw, list) or len(raw) != 3:
        raise MalformedPacket("clock echo must be [sender, t_sent, t_rcv]")
    return ClockEcho(
        sender=_string(raw[0], "echo sender"),
        t_sent=_number(raw[1], "echo t_sent"),
        t_rcv=_number(raw[2], "echo t_rcv"),
    )


def _report_entry(raw: Any) -> ReportEntry:
    if not isinstance(raw, list) or len(raw) != 10:
        raise MalformedPacket("report entry must be a list of 10 fields")
    sender, seq, msg_type, t_gen, t_sent, t_rcv, size, version, quality, data = raw
    return ReportEntry(
        sender=_string(sender, "entry sender"),
        seq=_count(seq, "entry seq"),
        type=_string(msg_type, "entry type"),
        t_gen=_number(t_gen, "entry t_gen"),
        t_sent=None if t_sent is None else _number(t_sent, "entry t_sent"),
        t_rcv=_number(t_rcv, "entry t_rcv"),
        size=_count(size, "entry size"),
        version=None if version is None else _count(version, "entry version"),
        quality=_number(quality, "entry quality"),
        data=_object(data, "entry data"),
    )
