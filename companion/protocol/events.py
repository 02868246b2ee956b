"""What the decoder hands back from ``next_event()``: frozen dataclasses under one base.

Don't subclass these; the shells dispatch on them with an ``isinstance`` chain.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from companion.protocol.records import Command, Report, Status
from utility_specs.message import Message

__all__ = [
    "AckReceived",
    "Address",
    "CommandReceived",
    "Event",
    "MessageExpired",
    "MessageReassembled",
    "PacketDropped",
    "ReportReceived",
    "StatusReceived",
]

Address = tuple[Any, ...]
"""A socket address as asyncio reports it: ``(host, port)`` or the IPv6 4-tuple."""


@dataclass(frozen=True, slots=True, kw_only=True)
class Event:
    """Base of every decoder event."""


@dataclass(frozen=True, slots=True, kw_only=True)
class MessageReassembled(Event):
    """All fragments of a message arrived and were authenticated."""

    message: Message
    """With ``receiver`` = the decoder's ``local_id``, ``t_sent`` from the first fragment and
    ``t_rcv`` = ``max(t_rcv, t_gen)`` (a drone clock ahead of ours must not make the
    message invalid); the raw arrival time is the ``t_rcv`` field below."""
    payload: bytes
    """The reassembled payload (e.g. JPEG bytes); empty for telemetry."""
    addr: Address
    """Where the last fragment came from."""
    t_rcv: float
    """Our clock when the last missing fragment arrived, seconds."""
    fragments: int
    """How many datagrams it took."""


@dataclass(frozen=True, slots=True, kw_only=True)
class MessageExpired(Event):
    """A partial message timed out or was evicted; the whole message is lost."""

    sender: str
    seq: int
    type: str
    fragments_missing: int
    fragment_count: int
    evicted: bool
    """True if pushed out by the memory bounds rather than by the reassembly timeout."""


@dataclass(frozen=True, slots=True, kw_only=True)
class ReportReceived(Event):
    """One datagram of a receiver report (each is self-contained)."""

    report: Report
    reporter: str
    """Sender id of the ground station."""
    report_number: int
    """Increases per report; parts of one report share it."""
    part_index: int
    part_count: int
    t_sent: float
    """T3: the reporter's clock when it sent the report."""
    t_rcv: float
    """T4: our clock when it arrived."""
    addr: Address


@dataclass(frozen=True, slots=True, kw_only=True)
class CommandReceived(Event):
    """A mission manager command; execute it at ``command.t_exec``."""

    command: Command
    sender: str
    """Sender id of the ground station."""
    t_sent: float
    """The ground's clock when it sent the command, seconds."""
    t_rcv: float
    """Our clock when it arrived, seconds."""
    addr: Address


@dataclass(frozen=True, slots=True, kw_only=True)
class StatusReceived(Event):
    """A command acknowledgement or status from a drone."""

    status: Status
    sender: str
    """Sender id of the drone."""
    t_sent: float
    """The drone's clock when it sent the status, seconds."""
    t_rcv: float
    """Our clock when it arrived, seconds."""
    addr: Address


AckReceived = StatusReceived
"""Alias: the brief's name for the same event."""


@dataclass(frozen=True, slots=True, kw_only=True)
class PacketDropped(Event):
    """A datagram was rejected; it is also counted in ``Decoder.counters[reason]``."""

    reason: str
    """Counter key: ``malformed``, ``bad_tag``, ``stale``, ``replayed``, ``oversize``..."""
    detail: str
    """Human-readable cause, for logs."""
    addr: Address
    sender: str | None = None
    """The sender, when the datagram was refused after its tag was verified (``stale``)."""
    skew_s: float | None = None
    """For ``stale``: the sender's clock minus ours, s. A drone whose clock is off (a
    Raspberry Pi has no real-time clock) is refused whole; this names it and by how much."""
