"""What reports, commands and status packets carry, as frozen dataclasses.

These are the values the encoder takes and the decoder's events hand back. Their
constructors validate, so a value that cannot go on the wire cannot be built.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from utility_specs.message import Message, Version

__all__ = [
    "EPOCH_STATUS",
    "ClockEcho",
    "ClockSample",
    "Command",
    "Report",
    "ReportEntry",
    "Status",
    "clock_sample",
    "entry_from_message",
    "report_messages",
]

EPOCH_STATUS = "epoch"
"""State of the STATUS a companion sends at start and when it refuses a command for another
boot: ``info = {"epoch": E}``; the ground station puts E into its commands to that drone."""


def _finite(name: str, value: float | None, *, optional: bool = False) -> None:
    if value is None and optional:
        return
    if value is None or not math.isfinite(value):
        raise ValueError(f"{name} must be a finite float, got {value!r}")


@dataclass(frozen=True, slots=True, kw_only=True)
class ReportEntry:
    """One message the ground station received since its previous report."""

    sender: str
    seq: int
    type: str
    t_gen: float
    """Generation time, sender's clock, seconds."""
    t_sent: float | None
    """When the sender encoded it (sender's clock), from the DATA header."""
    t_rcv: float
    """When the ground station completed its reassembly (ground clock), seconds."""
    size: int
    """``Message.size`` in bytes (what the goodput constraint counts)."""
    version: int | None = None
    """Index of the carried version (0 = best), ``None`` for messages without versions."""
    quality: float = 1.0
    """Quality of the carried version relative to the best one, in (0, 1] (eq. 4.33)."""
    data: Mapping[str, Any] = field(default_factory=dict)
    """Small utility-relevant fields (red, object, level...), JSON types only."""

    def __post_init__(self) -> None:
        if not self.sender or not self.type:
            raise ValueError("report entry needs a sender and a type")
        _finite("t_gen", self.t_gen)
        _finite("t_sent", self.t_sent, optional=True)
        _finite("t_rcv", self.t_rcv)
        if self.size < 0 or self.seq < 0:
            raise ValueError(f"size and seq must be >= 0, got {self.size}, {self.seq}")
        if not 0.0 < self.quality <= 1.0:
            raise ValueError(f"quality must be in (0, 1], got {self.quality}")
        if self.version is not None and self.version < 0:
            raise ValueError(f"version index must be >= 0, got {self.version}")


@dataclass(frozen=True, slots=True, kw_only=True)
class ClockEcho:
    """NTP-style timestamps for one drone: its last datagram's t_sent and our t_rcv of it."""

    sender: str
    t_sent: float
    """T1: the drone's clock when it sent its latest datagram we received."""
    t_rcv: float
    """T2: the ground clock when that datagram arrived."""

    def __post_init__(self) -> None:
        if not self.sender:
            raise ValueError("clock echo needs a sender")
        _finite("t_sent", self.t_sent)
        _finite("t_rcv", self.t_rcv)


@dataclass(frozen=True, slots=True, kw_only=True)
class Report:
    """A receiver report (ground -> drones): what arrived, plus clock echoes.

    The encoder may split one report into several self-contained datagrams; each decodes to
    a ``Report`` with a share of the echoes and entries (echoes first, from part 0 on).
    """

    entries: tuple[ReportEntry, ...] = ()
    echoes: tuple[ClockEcho, ...] = ()


@dataclass(frozen=True, slots=True, kw_only=True)
class Command:
    """A mission manager command, executed by each targeted drone at ``t_exec``.

    Names in use: ``start``, ``end``, ``set_params``, ``request_report`` (thesis sec. 3.3,
    fig. 3.7); the codec accepts any short name and JSON object ``args``.
    """

    command_id: int
    """Chosen by the ground station, 1..2**32-1; acknowledgements refer to it."""
    name: str
    t_exec: float
    """Absolute execution time on the fleet clock, seconds."""
    args: Mapping[str, Any] = field(default_factory=dict)
    target: str | None = None
    """Sender id of the one drone that should execute it; ``None`` for every drone."""

    def __post_init__(self) -> None:
        if not 1 <= self.command_id < 2**32:
            raise ValueError(f"command_id must be in 1..2**32-1, got {self.command_id}")
        if not self.name:
            raise ValueError("command name must not be empty")
        _finite("t_exec", self.t_exec)
        if self.target == "":
            raise ValueError("target must be a sender id or None (all drones)")


@dataclass(frozen=True, slots=True, kw_only=True)
class Status:
    """A drone's acknowledgement of a command or an unsolicited status (drone -> ground)."""

    state: str
    """E.g. ``ack`` (scheduled), ``done``, ``error``, ``running``, ``idle``."""
    command_id: int | None = None
    """The command this answers; ``None`` for an unsolicited status."""
    info: Mapping[str, Any] = field(default_factory=dict)
    """Current parameters, error text... JSON types only."""

    def __post_init__(self) -> None:
        if not self.state:
            raise ValueError("status state must not be empty")
        if self.command_id is not None and not 1 <= self.command_id < 2**32:
            raise ValueError(f"command_id must be in 1..2**32-1, got {self.command_id}")


@dataclass(frozen=True, slots=True, kw_only=True)
class ClockSample:
    """One NTP-style estimate from a report round trip (RFC 5905 sec. 8)."""

    offset_s: float
    """Ground clock minus drone clock: ((T2 - T1) + (T3 - T4)) / 2."""
    rtt_s: float
    """Round trip without the ground's hold time: (T4 - T1) - (T3 - T2)."""


def clock_sample(echo: ClockEcho, *, t_report_sent: float, t_report_rcv: float) -> ClockSample:
    """Offset and round trip from an echo (T1, T2), the report's t_sent (T3) and our t_rcv (T4)."""
    t1, t2, t3, t4 = echo.t_sent, echo.t_rcv, t_report_sent, t_report_rcv
    return ClockSample(offset_s=((t2 - t1) + (t3 - t4)) / 2.0, rtt_s=(t4 - t1) - (t3 - t2))


def entry_from_message(message: Message, *, t_rcv: float) -> ReportEntry:
    """The report entry the ground station sends for a reassembled message."""
    return ReportEntry(
        sender=message.sender,
        seq=message.seq,
        type=message.type,
        t_gen=message.t_gen,
        t_sent=message.t_sent,
        t_rcv=t_rcv,
        size=message.size,
        version=message.version,
        quality=message.quality,
        data=message.data,
    )


def report_messages(entries: Sequence[ReportEntry], *, receiver: str) -> list[Message]:
    """Report entries as delivered ``Message``s (receiver set, t_rcv set) for the optimiser.

    The ground clock and a drone clock may disagree, so a ``t_rcv`` earlier than ``t_gen``
    is clamped to ``t_gen`` (``Message`` forbids reception before generation); the raw
    value stays in the entry for delay estimation. A report does not list every version of
    a message, so a message received in some version carries one version named
    ``received`` with that version's size and quality (``version=0``); its original index is
    ``entry.version``.
    """
    messages = []
    for e in entries:
        versions: tuple[Version, ...] = ()
        if e.version is not None:
            versions = (Version(name="received", size=e.size, quality=e.quality),)
        messages.append(
            Message(
                sender=e.sender,
                seq=e.seq,
                type=e.type,
                t_gen=e.t_gen,
                size=e.size,
                receiver=receiver,
                t_sent=e.t_sent,
                t_rcv=max(e.t_rcv, e.t_gen),
                data=dict(e.data),
                versions=versions,
                version=0 if versions else None,
            )
        )
    return messages
